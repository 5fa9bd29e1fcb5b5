"""The paper's Table 1 (Hansen et al. 2018), for side-by-side comparison: (G, T, D, S mean, S std) per
(technique, agent speed, rollout steps). Some published rows do not sum to 100; they are kept as printed."""

from __future__ import annotations

PAPER_TABLE1: dict[tuple[str, float, int], tuple[int, int, int, int, int]] = {
    ("oracle", 1.0, 1): (100, 0, 0, 34, 17),
    ("oracle", 1.0, 3): (100, 0, 0, 36, 18),
    ("oracle", 1.0, 5): (100, 0, 0, 45, 28),
    ("oracle", 1.0, 10): (100, 4, 0, 68, 49),
    ("mid", 1.0, 1): (78, 0, 22, 33, 17),
    ("mid", 1.0, 3): (88, 0, 12, 40, 18),
    ("mid", 1.0, 5): (91, 2, 7, 65, 40),
    ("mid", 1.0, 10): (52, 25, 23, 111, 67),
    ("samples5", 1.0, 1): (84, 0, 16, 34, 17),
    ("samples5", 1.0, 3): (94, 1, 5, 46, 27),
    ("samples5", 1.0, 5): (89, 5, 6, 75, 51),
    ("samples5", 1.0, 10): (55, 23, 22, 112, 70),
    ("samples10", 1.0, 1): (85, 0, 15, 35, 18),
    ("samples10", 1.0, 3): (88, 0, 12, 46, 26),
    ("samples10", 1.0, 5): (89, 9, 2, 76, 56),
    ("samples10", 1.0, 10): (55, 31, 14, 124, 68),
    ("oracle", 0.5, 1): (72, 25, 3, 187, 151),
    ("oracle", 0.5, 3): (67, 32, 1, 209, 154),
    ("oracle", 0.5, 5): (60, 40, 0, 224, 64),
    ("oracle", 0.5, 10): (66, 34, 0, 216, 156),
    ("samples5", 0.5, 1): (31, 3, 55, 97, 107),
    ("samples5", 0.5, 3): (46, 21, 33, 196, 153),
    ("samples5", 0.5, 5): (41, 3, 27, 259, 155),
    ("samples5", 0.5, 10): (39, 46, 15, 294, 143),
}

#: "A random agent reached the goal once at 2× speed and never at 1×" (goals out of 100).
PAPER_RANDOM_GOALS = {1.0: 1, 0.5: 0}
