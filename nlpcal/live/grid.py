"""Coverage of the sphere of field directions on an equal-area grid, and where to turn next.

The grid is the recursive zonal equal-area partition of Leopardi [1] for `CELLS` = 80 cells:
a cap at each pole and collars between them, each collar cut into sectors of equal longitude.
The collars' heights in z are set so that every cell has exactly the area 4 pi / 80 sr (by
Archimedes' hat-box theorem a collar of height h has area 2 pi h), and their sector counts
follow [1], so the cells are near square (about 23 deg across) rather than the thin slices of
a latitude-longitude grid near its poles. A cell is covered when at least `CELL_SAMPLES`
samples of the corrected field point into it.

References
----------
[1] Leopardi, P. (2006). A partition of the unit sphere into regions of equal area and small
    diameter. Electronic Transactions on Numerical Analysis 25, 309-327.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

#: Cells of the grid, all of area 4 pi / CELLS sr (ArduPilot's onboard calibrator masks 80).
CELLS = 80
#: Samples in a cell for it to count as covered (one stray sample is not a visit). [1]
CELL_SAMPLES = 2
#: Covered fraction of the cells the live calibration asks for before it stops (default). [1]
COVERAGE_TARGET = 0.9


@cache
def zones() -> tuple:
    """(cells per zone from the north pole down, the zones' upper z bounds, first cell of each):
    Leopardi's [1] collars for CELLS cells, with heights that make every cell's area equal."""
    cap = 2.0 * np.arcsin(np.sqrt(1.0 / CELLS))  # polar cap of one cell's area [rad]
    collars = max(1, round((np.pi - 2.0 * cap) / np.sqrt(4.0 * np.pi / CELLS)))
    height = (np.pi - 2.0 * cap) / collars  # of a collar in colatitude [rad]
    counts, carry = [1], 0.0
    for i in range(collars):  # the ideal count of each collar, rounded with the carry of [1]
        top, bottom = cap + i * height, cap + (i + 1) * height
        ideal = (np.cos(top) - np.cos(bottom)) * CELLS / 2.0 + carry
        counts.append(round(ideal))
        carry = ideal - counts[-1]
    counts.append(1)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    upper = 1.0 - 2.0 * first / CELLS  # z at the top of each zone
    return np.array(counts), upper, first


def cell_index(directions) -> np.ndarray:
    """(N,) the grid cell of each direction (N, 3) (any length but zero), numbered from the
    north pole (+z) down and, within a zone, from +x counter-clockwise about +z."""
    v = np.asarray(directions, dtype=float)
    unit = v / np.linalg.norm(v, axis=1, keepdims=True)
    counts, upper, first = zones()
    zone = np.clip(np.searchsorted(-upper, -unit[:, 2], side="right") - 1, 0, len(counts) - 1)
    longitude = np.mod(np.arctan2(unit[:, 1], unit[:, 0]), 2.0 * np.pi)
    sectors = counts[zone]
    sector = np.minimum((longitude / (2.0 * np.pi) * sectors).astype(int), sectors - 1)
    return first[zone] + sector


def cell_centres() -> np.ndarray:
    """(CELLS, 3) the unit vector through the middle (in z and longitude) of each cell. [1]"""
    counts, upper, first = zones()
    lower = np.append(upper[1:], -1.0)
    zone = np.repeat(np.arange(len(counts)), counts)
    sector = np.arange(CELLS) - first[zone]
    z = np.where(counts[zone] == 1, np.sign(upper[zone] + lower[zone]), 0.5 * (upper + lower)[zone])
    phi = (sector + 0.5) * 2.0 * np.pi / counts[zone]
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def direction_name(vector) -> str:
    """A direction in the sensor's axes, in words: "+x -z" names the axes whose components
    reach half the largest one's."""
    v = np.asarray(vector, dtype=float)
    largest = float(np.max(np.abs(v)))
    parts = [
        f"{'+' if v[k] > 0 else '-'}{axis}"
        for k, axis in enumerate("xyz")
        if abs(v[k]) >= 0.5 * largest
    ]
    return " ".join(parts)


@dataclass(frozen=True)
class Coverage:
    """Which cells of the grid the corrected field visited.

    counts : (CELLS,) samples per cell. target : the covered fraction that completes it. [1]
    next_direction : (3,) the middle of the uncovered cell
    that has the most uncovered neighbours around it (the largest hole), or None when all are
    covered: where the field should point next, in the sensor's axes. [1]
    """

    counts: np.ndarray
    next_direction: np.ndarray | None
    target: float = COVERAGE_TARGET

    @property
    def covered(self) -> np.ndarray:
        return self.counts >= CELL_SAMPLES

    @property
    def fraction(self) -> float:
        return float(np.count_nonzero(self.covered)) / CELLS

    @property
    def complete(self) -> bool:
        return self.fraction >= self.target

    def to_dict(self) -> dict:
        """The "coverage" block of a live update."""
        nxt = self.next_direction
        return {
            "cells": CELLS,
            "covered": int(np.count_nonzero(self.covered)),
            "fraction": self.fraction,
            "target_fraction": self.target,
            "complete": self.complete,
            "cell_samples": [int(c) for c in self.counts],
            "next_direction": None if nxt is None else [float(x) for x in nxt],
            "turn_to": None if nxt is None else direction_name(nxt),
        }


def coverage(directions, target: float = COVERAGE_TARGET) -> Coverage:
    """The coverage of the grid by the directions (N, 3) of the corrected field; complete at
    `target`, a fraction of the cells. [1]"""
    counts = np.bincount(cell_index(directions), minlength=CELLS) if len(directions) else None
    counts = np.zeros(CELLS, dtype=int) if counts is None else counts
    missing = counts < CELL_SAMPLES
    if not missing.any():
        return Coverage(counts, None, target)
    centres = cell_centres()
    # the hole: weigh every uncovered cell by the uncovered cells within 45 deg of it
    near = (centres @ centres.T) > np.cos(np.radians(45.0))
    score = (near[:, missing].sum(axis=1)) * missing
    return Coverage(counts, centres[int(np.argmax(score))], target)
