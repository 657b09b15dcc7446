"""Every numerical tolerance and threshold of the package, in one place.

Units are in the names: ``_M`` metres, ``_PX`` pixels, ``_RAD`` radians.
"""

#: below this rotation angle, axis-angle <-> matrix use Taylor expansions
SMALL_ANGLE_RAD = 1e-6
#: within this of pi, the rotation axis is read from R + I instead of the skew part
NEAR_PI_RAD = 1e-3
#: |cross(forward, up)| below this means the look-at up vector is parallel to the view
LOOK_AT_PARALLEL = 1e-6
#: points closer to the camera plane than this cannot be projected
MIN_PROJECTION_DEPTH_M = 1e-6
#: orthonormality check for rotation matrices given by users
ROTATION_ORTHONORMAL = 1e-4
#: consecutive rings of the procedural probe must differ in height or radius by more than this
PROBE_RING_STEP_M = 1e-7
#: slack added to the distance bound when culling probe triangles, absorbing rounding
PROBE_SDF_PRUNE_SLACK_M = 1e-9
#: below this SDF gradient norm (m/m) the probe's surface normal is undefined and returned as zero
PROBE_SDF_MIN_GRADIENT = 1e-9
