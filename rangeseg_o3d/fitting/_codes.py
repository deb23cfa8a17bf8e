"""The fitters' shared numbers: refusal codes, the rows of a curved result, the radius limit.

A leaf module (no imports): the compiled fits (:mod:`._compiled`), the decision
(:mod:`._decide`) and the wording of a refusal (:func:`._common.refusal`) all read the
same codes from here.
"""

# A radius above this many times the rms spread of the points means a cap of under
# ~0.1 deg: the points are flat, and Levenberg-Marquardt would chase r -> infinity.
RADIUS_LIMIT = 1e3

ACCEPTED = 0
TOO_FEW = 1  # fewer points than the model needs
COLLINEAR = 2  # points coincident or collinear
COPLANAR = 3  # points coplanar: no curvature to fit
SINGULAR = 4  # the algebraic sphere system is singular
RUNAWAY = 5  # the radius ran beyond RADIUS_LIMIT x the patch size
NOT_CONVERGED = 6  # Levenberg-Marquardt did not converge
DIVERGED = 7  # non-finite parameters or a radius <= 0
NO_BETTER = 8  # rms not below the plane's
FLAT = 9  # sagitta not above the rms: the curvature is noise
RMS_OVER = 10  # rms over the kind's threshold
RADIUS_OVER = 11  # radius over max_radius
ARC_UNDER = 12  # arc (cylinder) or cap (sphere) under min_arc
GAIN_UNDER = 13  # not curvature_gain x better than the plane
NON_FINITE = 14  # a point is NaN or infinite (the wrappers word it with the count)

MIN_POINTS = (0, 3, 4, 5)  # points each kind needs at least, indexed by kind (NONE, PLANE, SPHERE, CYLINDER)

# Rows of a curved result (:func:`._decide.cylinder_checked`, :func:`._decide.sphere_checked`): parameters
# in the scaled frame, then statistics. A sphere uses slots 0-2 for its centre.
CURVED_SIZE = 11
RADIUS, RMS, INLIERS, ARC, CONVERGED = 6, 7, 8, 9, 10
