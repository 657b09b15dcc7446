"""Every numerical tolerance of the ``models`` package and its tests, in one place.

``models`` may not import :mod:`datagen`, so it keeps its own list beside
:mod:`hupbench.core.tolerances`.
"""

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
