"""The 29 keypoints: names, order, parents and skeleton edges.

This module is the single owner of keypoint order. Everything else (the hand
model, the annotation writer, the reader, the metrics, the overlays) imports
from here.

Convention:
    29 keypoints = 21 hand joints + 8 probe box corners.
    Hand (OpenPose / FreiHAND order, as in HOPE-Net): 0 wrist; 1-4 thumb CMC,
    MCP, IP, tip; 5-8 index MCP, PIP, DIP, tip; 9-12 middle; 13-16 ring;
    17-20 little.
    Corners 21-28: the probe's oriented box in the probe frame, ordered as
    ``itertools.product((min, max), repeat=3)`` over (x, y, z), i.e. corner
    ``21 + 4*ix + 2*iy + iz`` has x = (min, max)[ix], y = (min, max)[iy],
    z = (min, max)[iz].
"""

from __future__ import annotations

import itertools

NUM_HAND = 21
NUM_CORNERS = 8
NUM_KEYPOINTS = NUM_HAND + NUM_CORNERS

FINGERS = ("thumb", "index", "middle", "ring", "little")
_FINGER_JOINTS = {
    "thumb": ("cmc", "mcp", "ip", "tip"),
    "index": ("mcp", "pip", "dip", "tip"),
    "middle": ("mcp", "pip", "dip", "tip"),
    "ring": ("mcp", "pip", "dip", "tip"),
    "little": ("mcp", "pip", "dip", "tip"),
}

HAND_NAMES: tuple[str, ...] = ("wrist",) + tuple(
    f"{finger}_{joint}" for finger in FINGERS for joint in _FINGER_JOINTS[finger]
)

#: corner index bits (ix, iy, iz), each 0 = min, 1 = max, in the documented order
CORNER_BITS: tuple[tuple[int, int, int], ...] = tuple(itertools.product((0, 1), repeat=3))
CORNER_NAMES: tuple[str, ...] = tuple(
    "probe_corner_" + "".join(("-", "+")[b] + axis for b, axis in zip(bits, "xyz"))
    for bits in CORNER_BITS
)

KEYPOINT_NAMES: tuple[str, ...] = HAND_NAMES + CORNER_NAMES

HAND_SLICE = slice(0, NUM_HAND)
CORNER_SLICE = slice(NUM_HAND, NUM_KEYPOINTS)

#: first OpenPose index of each finger's chain (CMC/MCP), 4 keypoints per finger
FINGER_START = {finger: 1 + 4 * i for i, finger in enumerate(FINGERS)}
FINGERTIPS: tuple[int, ...] = tuple(FINGER_START[f] + 3 for f in FINGERS)

#: parent of each hand keypoint in the kinematic chain (-1 for the wrist)
HAND_PARENTS: tuple[int, ...] = (-1,) + tuple(
    0 if k == 0 else FINGER_START[finger] + k - 1 for finger in FINGERS for k in range(4)
)

HAND_EDGES: tuple[tuple[int, int], ...] = tuple(
    (parent, child) for child, parent in enumerate(HAND_PARENTS) if parent >= 0
)

#: the 12 box edges: corners that differ in exactly one bit
CORNER_EDGES: tuple[tuple[int, int], ...] = tuple(
    (NUM_HAND + a, NUM_HAND + b)
    for a, b in itertools.combinations(range(NUM_CORNERS), 2)
    if sum(x != y for x, y in zip(CORNER_BITS[a], CORNER_BITS[b])) == 1
)

SKELETON_EDGES: tuple[tuple[int, int], ...] = HAND_EDGES + CORNER_EDGES

# MANO's 16-joint kinematic tree: 0 wrist; index 1-3, middle 4-6, little 7-9,
# ring 10-12, thumb 13-15 (each chain proximal to distal).
MANO_FINGER_ORDER = ("index", "middle", "little", "ring", "thumb")
MANO_NUM_JOINTS = 16
MANO_PARENTS: tuple[int, ...] = (-1,) + tuple(
    0 if k == 0 else 1 + 3 * i + k - 1 for i in range(5) for k in range(3)
)

#: OpenPose index of each MANO joint (the three articulated joints of each finger)
MANO_TO_OPENPOSE: tuple[int, ...] = (0,) + tuple(
    FINGER_START[finger] + k for finger in MANO_FINGER_ORDER for k in range(3)
)

#: OpenPose fingertip index -> MANO joint whose transform carries it (the last of its chain)
TIP_PARENT_MANO: dict[int, int] = {
    FINGER_START[finger] + 3: 1 + 3 * i + 2 for i, finger in enumerate(MANO_FINGER_ORDER)
}


def finger_of(openpose_index: int) -> str:
    """Name of the finger a hand keypoint belongs to, or ``"wrist"``.

    Args:
        openpose_index: int in [0, 21).

    Returns:
        One of ``FINGERS`` or ``"wrist"``.
    """
    assert 0 <= openpose_index < NUM_HAND, openpose_index
    if openpose_index == 0:
        return "wrist"
    return FINGERS[(openpose_index - 1) // 4]
