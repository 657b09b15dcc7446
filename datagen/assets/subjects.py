"""Subjects: adult hands of many sizes, drawn from anthropometric tables, each made into a :class:`HandSpec`.

Hand length (wrist crease to the tip of the middle finger) and metacarpal hand breadth (across the metacarpal
heads) of adults, Pheasant and Haslegrave, Bodyspace, 3rd ed. (2006), hand
dimensions of British adults, millimetres:

=========================  =====  =====  =====  ====
                             5th   50th   95th    SD
=========================  =====  =====  =====  ====
women, hand length           159    174    189     9
men, hand length             173    189    205    10
women, hand breadth           69     76     83     4
men, hand breadth             78     87     95     5
=========================  =====  =====  =====  ====

Each subject's length and breadth are drawn from a bivariate normal of its sex (the 50th percentile as mean,
the SD above) with an assumed within-sex correlation of :data:`LENGTH_BREADTH_CORRELATION` (0.6: hand length
and breadth share overall body size but vary apart, e.g. long narrow hands), truncated to the spec's ranges by
redrawing. Two small spreads complete the hand: the finger/palm length ratio (a factor on the tables' ratio,
SD :data:`FINGER_RATIO_SD`) and the thickness of fingers and palm (a factor, SD :data:`THICKNESS_SD`), each
truncated at two SD. :meth:`Subject.hand_spec` solves the hand's scale and breadth factor so that the built
hand's measured length and breadth (:attr:`HandModel.length_mm`, :attr:`HandModel.breadth_mm`) match the draw.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from hupbench.core.errors import BadValueError
from hupbench.core.input_checks import check_int, check_number
from hupbench.datagen.assets.hand_anatomy import FACTOR_RANGE, HandSpec, rest_skeleton

#: (mean = 50th percentile, SD) in mm, per sex (0 woman, 1 man): Pheasant and Haslegrave (2006), module table
HAND_LENGTH_MM = {0: (174.0, 9.0), 1: (189.0, 10.0)}
HAND_BREADTH_MM = {0: (76.0, 4.0), 1: (87.0, 5.0)}
#: assumed within-sex correlation of hand length and hand breadth
LENGTH_BREADTH_CORRELATION = 0.6
FINGER_RATIO_SD = 0.03
THICKNESS_SD = 0.05
#: adult sizes a subject range must lie within, mm: beyond every adult 1st-99th percentile of both sexes
ADULT_HAND_LENGTH_MM = (130.0, 230.0)
ADULT_HAND_BREADTH_MM = (55.0, 115.0)
#: breadth / length a drawn hand may have (adults: about 0.40-0.50); beyond it the hand's breadth factor would
#: leave :data:`hupbench.datagen.assets.hand_anatomy.FACTOR_RANGE`
BREADTH_PER_LENGTH = (0.36, 0.53)
#: how close a built hand's measured length and breadth come to the subject's, mm
MATCH_MM = 0.8
#: the breadth's change per unit breadth factor on the tables' hand, mm: the index-to-little MCP spacing
#: (:data:`hupbench.datagen.assets.hand_anatomy._MCP_Z_MM`); the Newton step of :meth:`Subject.hand_spec`
_BREADTH_SLOPE_MM = 53.0
#: the tables' hand's measured breadth (HandSpec()), mm, and its change per unit thickness factor (the index
#: and little knuckles' radii, :data:`hupbench.datagen.assets.hand_anatomy.FINGER_RADII_MM` plus 1.2 mm each):
#: the first guess of :meth:`Subject.hand_spec`'s breadth factor
_TABLE_BREADTH_MM, _THICKNESS_SLOPE_MM = 74.0, 19.2
_MAX_SOLVE_STEPS = 8
MAX_SUBJECTS = 100_000


def _check_range(value, name: str, bounds: tuple[float, float]) -> tuple[float, float]:
    """``value`` as (low, high) when it is two numbers, low < high, both within ``bounds``."""
    low, high = bounds
    pair = tuple(value) if isinstance(value, (list, tuple)) else ()
    message = (f"{name} must be [low, high] with {low:g} <= low < high <= {high:g} mm (adult sizes), "
               f"got {value!r}")
    if len(pair) != 2:
        raise BadValueError(message)
    try:
        pair = tuple(check_number(v, name, low, high) for v in pair)
    except BadValueError:
        raise BadValueError(message) from None
    if pair[0] >= pair[1]:
        raise BadValueError(message)
    return pair


@dataclass(frozen=True)
class SubjectSpec:
    """Who holds the probe: how many subjects and the adult population they are drawn from (``conf/subjects``).

    Attributes:
        count: how many subjects (one grasp each).
        seed: the draw's seed.
        women_fraction: the share of women, 0..1 (rounded to whole subjects).
        hand_length_mm: [low, high] the length draws are truncated to, mm.
        hand_breadth_mm: [low, high] the breadth draws are truncated to, mm.
    """

    count: int = 60
    seed: int = 0
    women_fraction: float = 0.5
    hand_length_mm: tuple = (150.0, 220.0)
    hand_breadth_mm: tuple = (64.0, 100.0)

    def __post_init__(self) -> None:
        check_int(self.count, "count", 1, MAX_SUBJECTS)
        check_int(self.seed, "seed", 0, 2**32 - 1)
        check_number(self.women_fraction, "women_fraction", 0.0, 1.0)
        object.__setattr__(self, "hand_length_mm",
                           _check_range(self.hand_length_mm, "hand_length_mm", ADULT_HAND_LENGTH_MM))
        object.__setattr__(self, "hand_breadth_mm",
                           _check_range(self.hand_breadth_mm, "hand_breadth_mm", ADULT_HAND_BREADTH_MM))
        length, breadth = self.hand_length_mm, self.hand_breadth_mm
        if breadth[1] < BREADTH_PER_LENGTH[0] * length[0] or breadth[0] > BREADTH_PER_LENGTH[1] * length[1]:
            raise BadValueError(f"hand_breadth_mm {list(breadth)} and hand_length_mm "
                                f"{list(length)} admit no hand: breadth / length must be within "
                                f"{BREADTH_PER_LENGTH[0]:g}..{BREADTH_PER_LENGTH[1]:g}")


@dataclass(frozen=True)
class Subject:
    """One drawn subject.

    Attributes:
        index: its place in the draw. sex: 0 woman, 1 man.
        length_mm, breadth_mm: target hand length and metacarpal breadth, mm.
        finger_ratio: phalanx lengths over wrist-to-MCP lengths, relative to the tables' hand (1.0).
        thickness: :attr:`HandSpec.thickness`.
    """

    index: int
    sex: int
    length_mm: float
    breadth_mm: float
    finger_ratio: float
    thickness: float

    def hand_spec(self, voxel_m: float = HandSpec.voxel_m) -> HandSpec:
        """The hand whose measured length and breadth are this subject's (within :data:`MATCH_MM`).

        Length is the skeleton's and linear in the scale, so the scale is solved exactly; the breadth is
        measured on the built mesh and its factor corrected by Newton steps of slope :data:`_BREADTH_SLOPE_MM`.

        Args:
            voxel_m: the mesh's grid step (:attr:`HandSpec.voxel_m`); the measure depends on it slightly.
        """
        return _solve_hand(self, voxel_m)


@functools.lru_cache(maxsize=256)
def _solve_hand(subject: Subject, voxel_m: float) -> HandSpec:
    from hupbench.datagen.assets.hand import build_hand

    palm, fingers = subject.finger_ratio ** -0.5, subject.finger_ratio ** 0.5
    scale = subject.length_mm / (np.linalg.norm(rest_skeleton(HandSpec(palm=palm, fingers=fingers))[1][1]) * 1e3)
    breadth = float(np.clip(1.0 + (subject.breadth_mm / scale - _TABLE_BREADTH_MM
                                   - _THICKNESS_SLOPE_MM * (subject.thickness - 1.0)) / _BREADTH_SLOPE_MM,
                            *FACTOR_RANGE))
    for _ in range(_MAX_SOLVE_STEPS):
        unit = HandSpec(palm=palm, fingers=fingers, breadth=breadth, thickness=subject.thickness)
        tips = rest_skeleton(unit)[1]
        scale = subject.length_mm / (np.linalg.norm(tips[1]) * 1e3)  # MANO finger order: middle second
        spec = HandSpec(float(scale), palm, fingers, breadth, subject.thickness, voxel_m=voxel_m)
        error = subject.breadth_mm - build_hand(spec).breadth_mm
        if abs(error) <= MATCH_MM:
            return spec
        breadth = float(np.clip(breadth + error / (scale * _BREADTH_SLOPE_MM), *FACTOR_RANGE))
    raise AssertionError(f"hand of {subject} not solved: breadth off by {error:.2f} mm")


def _draw_one(rng: np.random.Generator, sex: int, spec: SubjectSpec) -> tuple[float, float]:
    """(length, breadth) mm of one subject of ``sex``, redrawn until within the spec's ranges."""
    (ml, sl), (mb, sb) = HAND_LENGTH_MM[sex], HAND_BREADTH_MM[sex]
    r = LENGTH_BREADTH_CORRELATION
    while True:
        z1, z2 = rng.standard_normal(2)
        length, breadth = ml + sl * z1, mb + sb * (r * z1 + np.sqrt(1.0 - r * r) * z2)
        if (spec.hand_length_mm[0] <= length <= spec.hand_length_mm[1]
                and spec.hand_breadth_mm[0] <= breadth <= spec.hand_breadth_mm[1]
                and BREADTH_PER_LENGTH[0] <= breadth / length <= BREADTH_PER_LENGTH[1]):
            return float(length), float(breadth)


def _truncated(rng: np.random.Generator, sd: float) -> float:
    """1 + a normal of SD ``sd`` truncated at two SD."""
    while abs(z := rng.standard_normal()) > 2.0:
        pass
    return float(1.0 + sd * z)


def draw_subjects(spec: SubjectSpec) -> list[Subject]:
    """The spec's subjects: round(count x women_fraction) women and the rest men, in a seeded shuffled order.

    Returns:
        ``spec.count`` :class:`Subject`, the same for the same spec.
    """
    rng = np.random.default_rng(spec.seed)
    n_women = int(round(spec.count * spec.women_fraction))
    sexes = rng.permutation(np.r_[np.zeros(n_women, int), np.ones(spec.count - n_women, int)])
    subjects = []
    for i, sex in enumerate(sexes):
        length, breadth = _draw_one(rng, int(sex), spec)
        subjects.append(Subject(i, int(sex), length, breadth, _truncated(rng, FINGER_RATIO_SD),
                                _truncated(rng, THICKNESS_SD)))
    return subjects
