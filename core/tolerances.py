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
#: rotation matrices are orthonormal within this (an internal invariant, asserted)
ROTATION_ORTHONORMAL = 1e-4
#: consecutive rings of the procedural probe must differ in height or radius by more than this
PROBE_RING_STEP_M = 1e-7
#: slack added to the distance bound when culling probe triangles, absorbing rounding
PROBE_SDF_PRUNE_SLACK_M = 1e-9
#: below this SDF gradient norm (m/m) the probe's surface normal is undefined and returned as zero
PROBE_SDF_MIN_GRADIENT = 1e-9

#: a hand keypoint is visible when the first surface on its pixel ray is the hand and lies at
#: most this far in front of it (joint centres sit up to ~12 mm under their skin)
VISIBLE_HAND_DEPTH_M = 0.016
#: ... and at most this far behind it (a fingertip on the silhouette whose pixel shows a surface
#: further back is not seen)
VISIBLE_HAND_BEHIND_M = 0.003
#: a probe box corner is visible when nothing on its pixel ray is more than this in front of it
VISIBLE_CORNER_DEPTH_M = 0.005
#: verify: 2D keypoints must equal the projection of the 3D ones within this
VERIFY_REPROJECTION_PX = 0.01
#: verify: 3D keypoints must equal those recomputed from the stored pose within this
VERIFY_KEYPOINT_M = 1e-4
#: verify: the protocol's look-at point must sit this close to (0, 0, z_ego) in the camera frame
#: (float32 keypoints at up to ~1 m round to ~6e-8 m)
VERIFY_LOOK_AT_M = 1e-6
#: verify: probe pixels (eroded mask), unprojected with their depth, lie this close to the probe surface
VERIFY_PROBE_SURFACE_M = 0.003
#: verify: the annotations' K must equal the manifest's within this
VERIFY_K_PX = 1e-6
#: verify: the images sit this close to the labels (pixels, per axis): measured on correct 256 px frames
#: within 0.07 px, a half-pixel shift 0.49-0.55 px (hupbench.datagen.dataset.verify_images.image_shift_px)
VERIFY_IMAGE_SHIFT_PX = 0.25
#: verify: the shift is measured from at least this many probe pixels on the probe's surface ...
VERIFY_SHIFT_MIN_PIXELS = 30
#: ... whose normals pin it down: the least-squares design (columns scaled to unit length) must have a
#: condition number below this
VERIFY_SHIFT_MAX_COND = 50.0
#: verify: finite-difference step for the probe's surface normals, metres
VERIFY_SDF_STEP_M = 1e-5
#: verify: the manifest's split floors must equal those the annotations give within this (mm; the same
#: float32 keypoints, summed in another order)
VERIFY_FLOOR_MM = 0.01
#: verify: away from the mask's edge, depth and mask agree on foreground; more disagreeing pixels
#: than this means one of them is another frame's (correct frames: at most 11 at 64-256 px; a depth
#: or seg file of another view: 71 or more at 64 px; docs/robustness.md, section verify)
VERIFY_MASK_DEPTH_PX = 24
#: verify: in a JPEG block near the object, an RGB pixel the mask calls background (1 pixel or more
#: from it) differs from the background when a channel is more than this many levels off its JPEG
#: encoding (correct frames: none above 40 at quality 95, a handful at 75 and 50)
VERIFY_BACKGROUND_LEVELS = 40
#: verify: in JPEG blocks of background only, the same with this many levels (correct frames: <= 2)
VERIFY_BACKGROUND_FAR_LEVELS = 12
#: verify: more such pixels than this means the RGB image or the mask is another frame's
VERIFY_BACKGROUND_PX = 16
#: verify glove colour: stored levels at or above this (and their neighbours) may be clipped by the renderer
VERIFY_GLOVE_CLIPPED_LEVEL = 235
#: verify glove colour: pixels with a channel below this level carry no colour to speak of
VERIFY_GLOVE_DARK_LEVEL = 8
#: verify glove colour: side of the pixel blocks whose mean colours are fitted (averaging halves
#: JPEG's chroma noise)
VERIFY_GLOVE_BLOCK_PX = 2
#: verify glove colour: JPEG noise of a stored pixel, levels (scales the plane distances)
VERIFY_GLOVE_NOISE_LEVELS = 2.0
#: verify glove colour: plane distances (in noise units) are clipped here before squaring
VERIFY_GLOVE_CLIP = 10.0
#: verify glove colour: the two frames of a view need this many usable blocks together
VERIFY_GLOVE_MIN_PAIR_BLOCKS = 8
#: verify glove colour: ... and this many each for the tighter limit below
VERIFY_GLOVE_MIN_BLOCKS = 4
#: verify glove colour: a view's two frames fail when their own gloves and lamps cost more than this
#: fraction of the exchanged ones' (correct pairs: at most 0.30 over 4,093 pairs of 256 px frames
#: at JPEG quality 95, 0.31 at quality 50; a copied image gives 1, swapped images 3.2 or more)
VERIFY_GLOVE_PAIR_RATIO = 0.55
#: verify glove colour: the limit when one of the two hands shows fewer than VERIFY_GLOVE_MIN_BLOCKS
#: (correct pairs then up to 0.44, swapped from 2.3)
VERIFY_GLOVE_PAIR_RATIO_FEW = 1.0
#: import-hup3d: the published meta's float32 camera matrices equal the renderer's within this
IMPORT_META_MATCH = 1e-4
#: import-hup3d: a frame's pose[:3] (float32 axis-angle) is a sphere view's rotation within this; the
#: published views lie 20 degrees or more apart
IMPORT_VIEW_RAD = 1e-3
#: import-hup3d: the published coords_2d equal coords_3d projected (float32 keypoints: ~1e-4 px)
IMPORT_COORDS_2D_PX = 0.01
#: a point set maps onto itself under a symmetry when every mapped point lies within this of a point
#: of the set, relative to the set's size (largest distance from its centroid)
SYMMETRY_REL_TOL = 1e-6
#: a dataset's corners are stored in float32 camera coordinates: taken back to the probe frame they
#: agree to about a micrometre, so the half-turn check of its corners allows this fraction of the box's size (~9 um)
CORNER_SYMMETRY_REL_TOL = 1e-4
#: a dataset's corners of different frames, taken back to the probe frame, must agree within this (metres)
CORNER_FRAME_TOL_M = 1e-5

# models (hupbench.models) and their tests

#: degrees of a learned adjacency below this fraction of its largest |entry| are raised to it,
#: so that D^-1/2 stays finite (every normalised entry is then at most 1 / sqrt(eps) = 1e3)
ADJACENCY_DEGREE_EPS = 1e-6

#: tests: HOPE-Net under CPU bf16 autocast vs fp32, relative L2 error of an output
#: (||p_bf16 - p_fp32|| / ||p_fp32|| over the batch). Measured in eval mode on random-init
#: models, (4, 3, 96, 96) normal inputs, seeds 0-59 x resnet10/resnet18 (120 models):
#: 3D output median 0.0030, worst 0.0114 -> bound 0.03;
BF16_AUTOCAST_REL_3D = 0.03
#: initial 2D output median 0.0048, worst 0.0064 -> bound 0.02;
BF16_AUTOCAST_REL_2D_INIT = 0.02
#: refined 2D output median 0.0039, worst 0.055 -> bound 0.1. The tail is wide because a
#: random-init refinement outputs almost nothing (RMS 0.01-0.1 against O(1) for the initial 2D),
#: so the same absolute bf16 rounding is a larger fraction of it.
BF16_AUTOCAST_REL_2D = 0.1

#: tests: channels_last vs contiguous input in eval mode, largest difference of any fp32 output
#: scaled by max(1, largest |output|): absolute for O(1) outputs, relative for the O(10-30)
#: features of a random-init ResNet-50. Measured worst 3.6e-6 (ResNet-50, 64 px, 10 seeds);
#: HOPE-Net worst 3.1e-6 over 120 models.
CHANNELS_LAST_REL = 1e-5
