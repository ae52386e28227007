"""`sofia perturb`: what-if copies of recorded bags with a shape added to one observable.

Would this campaign see a 1" error of this shape? ``perturb_bag(bag, out, 'fpi.x', '1.0*sin(2*pi*time_s/600)')``
writes the bag again with the shape added to every FPI column centroid (in arcsec, converted with the
camera's nominal scale), every other record unchanged, for `sofia compare` to look at. The shape is a
safe numpy expression (shapes) in the recorded variables of each row (variables); the copy is
rewrite's.
"""

from sofia_ros.perturb.observables import OBSERVABLES
from sofia_ros.perturb.run import PERTURBATION_FILE, Perturbation, perturb_bag
from sofia_ros.perturb.variables import CAMERA_SHAPE_VARIABLES, GYRO_SHAPE_VARIABLES

__all__ = ['CAMERA_SHAPE_VARIABLES', 'GYRO_SHAPE_VARIABLES', 'OBSERVABLES', 'PERTURBATION_FILE', 'Perturbation', 'perturb_bag']
