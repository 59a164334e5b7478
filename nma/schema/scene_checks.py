"""What makes a well-formed scene physically wrong, refused before any work: cells in pieces, points
on no material, a held or moved segment off the outer boundary, two segments that contradict each
other where they meet, a body nothing holds (SceneConfig's checks, nma.schema.scene)."""

from __future__ import annotations

import math

from ..errors import ConfigError


def _segment_distance(a, b) -> float:
    """Distance between two segments (points if of zero length) in the plane."""

    def point_segment(p, s):
        (x0, y0), (x1, y1) = s
        dx, dy = x1 - x0, y1 - y0
        L2 = dx * dx + dy * dy
        t = 0.0 if L2 == 0 else min(1.0, max(0.0, ((p[0] - x0) * dx + (p[1] - y0) * dy) / L2))
        return math.hypot(p[0] - x0 - t * dx, p[1] - y0 - t * dy)

    def cross(o, p, q):
        return (p[0] - o[0]) * (q[1] - o[1]) - (p[1] - o[1]) * (q[0] - o[0])

    (p0, p1), (q0, q1) = a, b
    d1, d2, d3, d4 = cross(p0, p1, q0), cross(p0, p1, q1), cross(q0, q1, p0), cross(q0, q1, p1)
    if (d1 * d2 < 0) and (d3 * d4 < 0):
        return 0.0  # proper crossing
    return min(
        point_segment(p0, b), point_segment(p1, b), point_segment(q0, a), point_segment(q1, a)
    )


def _rank(rows: list[list[float]], tol: float) -> tuple[int, list[list[float]]]:
    """Rank of a small matrix with 3 columns by Gaussian elimination, and a basis of its null
    space."""
    m = [list(r) for r in rows]
    pivots, r = [], 0
    for c in range(3):
        best = max(range(r, len(m)), key=lambda i: abs(m[i][c]), default=None)
        if best is None or abs(m[best][c]) <= tol:
            continue
        m[r], m[best] = m[best], m[r]
        m[r] = [v / m[r][c] for v in m[r]]
        for i in range(len(m)):
            if i != r and m[i][c]:
                m[i] = [vi - m[i][c] * vr for vi, vr in zip(m[i], m[r])]
        pivots.append(c)
        r += 1
    null = []
    for free in (c for c in range(3) if c not in pivots):
        v = [0.0, 0.0, 0.0]
        v[free] = 1.0
        for i, c in enumerate(pivots):
            v[c] = -m[i][free]
        null.append(v)
    return r, null


class SceneChecks:
    """The physical checks of nma.schema.scene.SceneConfig, a part of it: they read its fields."""

    def _filled(self, i: int, j: int) -> bool:
        """Whether cell (column i, row j from the bottom) holds material (False outside the
        grid)."""
        rows = self.rows()[::-1]
        return 0 <= j < len(rows) and 0 <= i < len(rows[0]) and rows[j][i] != "."

    def _tol(self) -> float:
        return 1e-9 * max(abs(v) for v in self.breaks("x") + self.breaks("y") + [1.0])

    def _check_one_piece(self):
        """Cells joined through shared edges (a corner alone is a hinge of one control point)."""
        nx, ny = len(self.rows()[0]), len(self.rows())
        filled = {(i, j) for i in range(nx) for j in range(ny) if self._filled(i, j)}
        if not filled:
            self.fail("cells", "holds no material (every cell is '.')", self.cells)
        seen, todo = set(), [min(filled)]
        while todo:
            i, j = todo.pop()
            if (i, j) in seen:
                continue
            seen.add((i, j))
            todo += [c for c in ((i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)) if c in filled]
        if seen != filled:
            apart = sorted((ny - j, i + 1) for i, j in filled - seen)
            self.fail(
                "cells",
                "must be one piece (cells joined through shared edges); the cells at (row, column) "
                f"{apart[:6]}{' ...' if len(apart) > 6 else ''}, counted from the top left from "
                "1, are apart from the rest",
            )

    def _check_in_material(self):
        """Tracked and pinned points lie on the cells' material (in or on a cell that is not '.');
        whether a tracked point falls in a pore is known only with the design (the discretisation
        says so)."""
        tol, xb, yb = self._tol(), self.breaks("x"), self.breaks("y")

        def cells_at(v, breaks):  # the cell indices whose closed interval holds v
            return [
                k for k, (b0, b1) in enumerate(zip(breaks, breaks[1:])) if b0 - tol <= v <= b1 + tol
            ]

        for path, points in (
            ("tracked", self.tracked.items()),
            ("pinned", ((None, p) for p in self.pinned)),
        ):
            for name, (x, y) in points:
                if not any(self._filled(i, j) for i in cells_at(x, xb) for j in cells_at(y, yb)):
                    what = f"point {name} at {[x, y]}" if name else f"point {[x, y]}"
                    self.fail(
                        path,
                        f"{what} lies on no material: the cells span x {xb[0]:g} to {xb[-1]:g}, y "
                        f"{yb[0]:g} to {yb[-1]:g}, and '.' cells are empty",
                    )

    def _boundary_problem(self, vertical: bool, line: float, lo: float, hi: float) -> str | None:
        """Why the piece [lo, hi] of the grid line x = line (vertical) or y = line is not outer
        boundary (material on exactly one side all along; a point: beside at least one boundary
        edge), or None."""
        tol = self._tol()
        breaks, across = (
            (self.breaks("y"), self.breaks("x"))
            if vertical
            else (self.breaks("x"), self.breaks("y"))
        )
        k = next((k for k, b in enumerate(across) if abs(b - line) <= tol), None)
        if k is None:
            return "it runs along no cell boundary"
        if lo < breaks[0] - tol or hi > breaks[-1] + tol:
            return f"it reaches beyond the cells ({breaks[0]:g} to {breaks[-1]:g})"
        on_edge = False
        for n, (b0, b1) in enumerate(zip(breaks, breaks[1:])):
            if not ((min(hi, b1) - max(lo, b0) > tol) if hi > lo else (b0 - tol <= lo <= b1 + tol)):
                continue
            sides = (
                [self._filled(k - 1, n), self._filled(k, n)]
                if vertical
                else [self._filled(n, k - 1), self._filled(n, k)]
            )
            if hi > lo and sides[0] == sides[1]:
                return (
                    f"between {b0:g} and {b1:g} it has "
                    f"{'material on both sides' if sides[0] else 'no material on either side'}"
                )
            on_edge |= sides[0] != sides[1]
        return None if on_edge else "the point is on no boundary edge"

    def _check_on_boundary(self, path: str, name: str, segment):
        """A held or moved segment must lie on the material's outer boundary: material on one side
        only."""
        (x0, y0), (x1, y1) = segment
        where = " ".join(
            filter(
                None,
                [
                    name,
                    str([list(p) for p in segment]),
                    "must lie on the material's outer boundary",
                ],
            )
        )
        if x0 != x1 and y0 != y1:
            self.fail(path, f"{where}, which is horizontal and vertical lines only")
        if (x0, y0) == (x1, y1):  # a point actuator: on a boundary edge either way
            problems = [
                self._boundary_problem(True, x0, y0, y0),
                self._boundary_problem(False, y0, x0, x0),
            ]
            problem = None if None in problems else problems[0]
        elif x0 == x1:
            problem = self._boundary_problem(True, x0, min(y0, y1), max(y0, y1))
        else:
            problem = self._boundary_problem(False, y0, min(x0, x1), max(x0, x1))
        if problem:
            self.fail(path, f"{where}; {problem}")

    def _check_no_contradiction(self):
        """Two segments that share a point must not prescribe one displacement component two ways
        there. Per component: None (free), 0 (held), or (actuation, coefficient) (moved by
        d[actuation])."""
        zero = lambda a, c: 0 if c == 0 else (a, c)
        held = [
            (f"group {g.name}", g.segment, [zero(g.actuation, c) for c in g.direction])
            for g in self.groups
        ] + [
            (
                f"scene.supports[{k}]",
                s.segment,
                [0 if c in s.fixed_components() else None for c in (0, 1)],
            )
            for k, s in enumerate(self.supports)
        ]
        for a in range(len(held)):
            for b in range(a + 1, len(held)):
                (na, sa, ma), (nb, sb, mb) = held[a], held[b]
                clash = any(x is not None and y is not None and x != y for x, y in zip(ma, mb))
                if clash and _segment_distance(sa, sb) <= self._tol():
                    raise ConfigError(
                        f"scene.{'groups' if na.startswith('group') else 'supports'}: {na} and "
                        f"{nb} touch but prescribe different motions where they meet"
                    )

    def _check_held(self):
        """The Dirichlet conditions must stop every rigid motion u = t + theta (-y, x); else the
        stiffness is singular.  Each held component at a point is one row [t_x, t_y, theta] of a
        3-column system.  A periodic scene is held by periodicity instead."""
        if getattr(self, "periodic", False):
            return self._check_periodic()
        rows = []
        for p in self.pinned:
            rows += [[1.0, 0.0, -p[1]], [0.0, 1.0, p[0]]]
        for g in self.groups:  # a moved segment holds its points to the actuation
            for p in g.segment:
                rows += [[1.0, 0.0, -p[1]], [0.0, 1.0, p[0]]]
        for s in self.supports:
            for p in s.segment:
                rows += [
                    [1.0, 0.0, -p[1]] if c == 0 else [0.0, 1.0, p[0]] for c in s.fixed_components()
                ]
        rank, free = _rank(rows, 1e-12)
        if rank == 3:
            return
        motions = []
        for t_x, t_y, theta in free:
            if abs(theta) < 1e-12:
                motions.append(f"moving along ({t_x + 0.0:g}, {t_y + 0.0:g})")
            else:
                motions.append(f"rotating about ({-t_y / theta + 0.0:g}, {t_x / theta + 0.0:g})")
        self.fail(
            "pinned",
            "with scene.groups and scene.supports leaves the body free to move (a singular "
            f"stiffness): nothing stops it {' or '.join(motions)}; pin two points (scene.pinned) "
            "or hold a segment (scene.supports, or an actuated group)",
        )

    def _check_periodic(self):
        """A periodic scene: F_bar is its load and periodicity holds it, so no group, no support and
        at most one pinned point (where the fluctuation is held at zero)."""
        if self.groups:
            self.fail("groups", "must be empty in a periodic scene (F_bar is its load)")
        if self.supports:
            self.fail("supports", "must be empty in a periodic scene (periodicity holds it)")
        if self.gravity is not None and any(self.gravity):
            self.fail(
                "gravity",
                "must be null in a periodic scene: a weight per cell is not a macroscopic load "
                "that periodicity can carry",
                self.gravity,
            )
        if self.tracked:
            self.fail(
                "tracked",
                "must be empty in a periodic scene: its path reports averages, not points",
                self.tracked,
            )
        if len(self.pinned) > 1:
            self.fail(
                "pinned",
                "must be at most one point in a periodic scene (where w = 0 removes translation)",
                self.pinned,
            )
        # an empty cell facing an empty cell across a seam: one void split by the seam, whose walls
        # neither contact nor the validity checks see across it
        rows = self.rows()
        seams = [
            f"row {r + 1} from the top" for r, row in enumerate(rows) if row[0] + row[-1] == ".."
        ]
        seams += [
            f"column {c + 1}" for c in range(len(rows[0])) if rows[0][c] + rows[-1][c] == ".."
        ]
        if seams:
            self.fail(
                "cells",
                f"has empty cells '.' facing each other across a periodic seam ({seams[0]}): the "
                "void straddles the seam, where contact and the validity checks cannot see its "
                "walls; shift the grid so that the void lies inside the box",
                self.cells,
            )
