"""Every numerical tolerance of the ``models`` package and its tests, in one place.

``models`` may not import :mod:`datagen`, so it keeps its own list beside
:mod:`datagen.tolerances`.
"""

#: degrees of a learned adjacency below this fraction of its largest |entry| are raised to it,
#: so that D^-1/2 stays finite (|output entries| <= sqrt(N / eps), about 5.4e3 for 29 nodes)
ADJACENCY_DEGREE_EPS = 1e-6

#: tests: HOPE-Net under bf16 autocast vs fp32, relative L2 error of the 3D output
#: (||p_bf16 - p_fp32|| / ||p_fp32|| over the batch). Measured on CPU, eval mode, random init,
#: 96 px inputs, 20 seeds x resnet10/resnet18: median 0.0041, worst 0.0097; bound = worst x ~2.
BF16_AUTOCAST_REL_3D = 0.02
#: tests: the same for the initial and refined 2D outputs (measured worst 0.0059, same runs)
BF16_AUTOCAST_REL_2D = 0.02

#: tests: channels_last vs contiguous input, largest absolute difference of any fp32 output
#: (measured below 2e-7 on CPU; outputs are O(0.1))
CHANNELS_LAST_ABS = 1e-5
