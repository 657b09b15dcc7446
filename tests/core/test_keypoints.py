import itertools


from hupbench.core import keypoints as kp


def test_counts_and_names():
    assert kp.NUM_KEYPOINTS == 29 and len(kp.KEYPOINT_NAMES) == 29
    assert len(set(kp.KEYPOINT_NAMES)) == 29
    assert kp.KEYPOINT_NAMES[0] == "wrist"
    assert kp.KEYPOINT_NAMES[1:5] == ("thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip")
    assert kp.KEYPOINT_NAMES[5:9] == ("index_mcp", "index_pip", "index_dip", "index_tip")
    assert kp.KEYPOINT_NAMES[17] == "little_mcp" and kp.KEYPOINT_NAMES[20] == "little_tip"
    assert kp.FINGERTIPS == (4, 8, 12, 16, 20)


def test_corner_order_is_product_of_min_max():
    assert kp.CORNER_BITS == tuple(itertools.product((0, 1), repeat=3))
    assert kp.KEYPOINT_NAMES[21] == "probe_corner_-x-y-z"
    assert kp.KEYPOINT_NAMES[22] == "probe_corner_-x-y+z"
    assert kp.KEYPOINT_NAMES[28] == "probe_corner_+x+y+z"


def test_skeleton_edges():
    assert len(kp.HAND_EDGES) == 20
    assert len(kp.CORNER_EDGES) == 12
    # each corner touches three box edges
    for c in range(21, 29):
        assert sum(c in e for e in kp.CORNER_EDGES) == 3
    # every finger chain starts at the wrist
    for finger, start in kp.FINGER_START.items():
        assert kp.HAND_PARENTS[start] == 0
        assert kp.HAND_PARENTS[start + 3] == start + 2


def test_mano_tree_maps_onto_openpose():
    assert kp.MANO_PARENTS[:4] == (-1, 0, 1, 2)
    assert kp.MANO_PARENTS[13] == 0 and kp.MANO_PARENTS[15] == 14
    # MANO joints land on all hand keypoints except the five tips, once each
    assert sorted(kp.MANO_TO_OPENPOSE) == sorted(set(range(21)) - set(kp.FINGERTIPS))
    # MANO 1 = index MCP, 7 = little MCP, 13 = thumb CMC
    assert kp.KEYPOINT_NAMES[kp.MANO_TO_OPENPOSE[1]] == "index_mcp"
    assert kp.KEYPOINT_NAMES[kp.MANO_TO_OPENPOSE[7]] == "little_mcp"
    assert kp.KEYPOINT_NAMES[kp.MANO_TO_OPENPOSE[13]] == "thumb_cmc"
    # parent relations agree between the two orders
    for j, parent in enumerate(kp.MANO_PARENTS):
        if parent >= 0:
            assert kp.HAND_PARENTS[kp.MANO_TO_OPENPOSE[j]] == kp.MANO_TO_OPENPOSE[parent]
    assert kp.TIP_PARENT_MANO[8] == 3 and kp.TIP_PARENT_MANO[4] == 15


def test_finger_of():
    assert kp.finger_of(0) == "wrist" and kp.finger_of(4) == "thumb" and kp.finger_of(20) == "little"
