"""Material models and the material library.

A phase's material is a `Material`: a model kind (one function per kind in this package, chosen
before tracing so an unused model costs nothing) and its constants (SI). The constants become
Params leaves (`params.phases[name][constant]`), so they can be batched and differentiated.
"""

from jaxmpm.materials.library import Material, known_keys, library_material, resolve_material
from jaxmpm.materials.models import MODELS, MatPoint, Model, model_of

__all__ = ["Material", "MODELS", "MatPoint", "Model", "known_keys", "library_material", "model_of", "resolve_material"]
