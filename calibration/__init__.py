"""calibration: fit the exchange drag coefficient C_d and the closure scale C_h of jaxmpm's
debris cloud to Piekutowski's feature velocities by gradient descent (optax), and the C_h table.

    python -m calibration table [--resolution R] [--out DIR]     # the seed's C_h sweep, one vmapped call
    python -m calibration fit [--resolution R] [--iterations N] [--start C_d,C_h] [--method adam|lbfgs] [--out DIR]
    python -m calibration synthetic [--truth C_d,C_h] [--start C_d,C_h]   # recover known values, small scene
"""

from calibration.data import Measurements as Measurements, load as load
