"""sofia_ros: SOFIA pointing-control emulation and calibration analysis on ROS 2."""

import os

# The linear algebra here is small (a few hundred unknowns) and the graph runs many processes on
# few cores: BLAS threads only fight each other (eigh of 192 x 192 measured 27x slower with
# OpenBLAS' default threads on a loaded 2-core machine). A user's own setting wins.
for _variable in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_variable, '1')

__version__ = '0.1.0'
