"""Numerics on arrays: shape functions, particle-grid transfers, the DDMP stencils, guarded
division and the compiler options and transfer forms the kernels use."""
