"""The D3Q19 lattice of the lattice-Boltzmann lighting model, and the relighting hull.

Directions (geist2008 sec. 2.2, steele2010 sec. 2.2)
----------------------------------------------------
The 24 points of the 4D lattice that are equidistant from the origin,

    (±1, 0, 0, ±1) (0, ±1, ±1, 0) (0, ±1, 0, ±1)
    (±1, 0, ±1, 0) (0, 0, ±1, ±1) (±1, ±1, 0, 0),

projected to 3D by dropping the fourth component give 18 distinct directions:
each of the 6 axial directions is the image of 2 points, each of the 12
"non-axial" (face-diagonal) directions the image of 1 — "axial directions then
receive double weights". A rest direction pointing from a site to itself is
added, for absorption and emission: 19 directions, the non-corner points of
the cube of unit radius. The module derives the multiplicities from the 4D
points at import and checks them against the table below.

Index order (fixed; the rest of the package and the stored bases rely on it)::

    0        rest ( 0, 0, 0)
    1 .. 6   axial: +x, -x, +y, -y, +z, -z
    7 .. 18  non-axial, opposite pairs adjacent:
             7 (+1,+1, 0)   8 (-1,-1, 0)   9 (+1,-1, 0)  10 (-1,+1, 0)
            11 (+1, 0,+1)  12 (-1, 0,-1)  13 (+1, 0,-1)  14 (-1, 0,+1)
            15 ( 0,+1,+1)  16 ( 0,-1,-1)  17 ( 0,+1,-1)  18 ( 0,-1,+1)

This is the order geist2008 eqs. (5)-(9) assume (row 0 rest, rows 1-6 axial,
rows 7-18 non-axial).

Weights
-------
``MULTIPLICITY[i]`` is the number of 4D points projecting onto ``c_i``: 2 for
axial, 1 for non-axial, 0 for rest; it sums to 24. ``WEIGHTS = MULTIPLICITY /
24`` are the scattering weights of geist2008 eqs. (6)-(7) (1/12 axial, 1/24
non-axial) and of the normalisation of eq. (8); they sum to 1 over the 18
moving directions (the rest direction gets weight 0: it does not take part
in the angular redistribution). They are a symmetric quadrature of the
sphere: ``sum_i w_i c_i = 0`` and ``sum_i w_i c_i c_i^T = I / 2``.

Step lengths and ordinate weights (the "ordinates" lattice of ``lb``)
--------------------------------------------------------------------
``STEP_LENGTHS[i] = |c_i|`` is the length of one lattice step along c_i in
units of the lattice spacing: 1 axial, sqrt(2) non-axial (0 rest).

Read as a discrete-ordinate scheme, each moving direction is an ordinate
n_i = c_i / |c_i| standing for a cone of directions, and the share of
isotropically scattered power it receives is a quadrature weight on the
sphere. geist2008's double axial weight (``WEIGHTS``) is the lattice-gas
condition that the fourth moments of the lattice *velocities* c_i are
isotropic, ``sum_i w_i c_ix^4 = 3 sum_i w_i c_ix^2 c_iy^2`` (2a + 8b = 12b, so
a = 2b, with a the axial and b the non-axial weight): right for particles that
move |c_i| per step. For ordinates the same condition on the unit vectors
n_i, ``sum_i w_i n_ix^4 = 3 sum_i w_i n_ix^2 n_iy^2`` (2a + 2b = 3b), with
6a + 12b = 1, gives ``ORDINATE_WEIGHTS``: a = 1/30 axial, b = 1/15 non-axial.
It is the one cubic-symmetric weighting of the 18 directions that integrates
every polynomial of degree <= 5 over the sphere exactly (odd degrees vanish
by symmetry; degree 2 holds for any a, b with 6a + 12b = 1; degree 4 fixes
a = b / 2), where ``WEIGHTS`` integrates only up to degree 3
(``sum w n_x^4`` = 1/4 instead of 1/5).

Relighting hull (steele2010 sec. 3.1)
-------------------------------------
The 18 unit directions ``c_i / |c_i|`` are the vertices of a convex
polyhedron with 32 triangular faces (the 8 triangles of the cuboctahedron plus
4 triangles of each of the 6 square pyramids capped by an axial direction).
``barycentric_weights(d)`` finds the face hit by the ray from the origin along
``d`` and returns its 3 lattice indices and the barycentric coordinates of the
hit point, normalised to sum to 1 as in steele2010 ("the weights sum to one,
thus conserving total energy"). Note that ``sum_k w_k n_k`` is the hit point
on the face, parallel to ``d`` but shorter than 1 (it is a point on a flat
face, not on the sphere).

Everything here is an immutable numpy array (``flags.writeable = False``) or a
tuple; nothing in the module can be modified by a caller.
"""

from __future__ import annotations

import itertools

import numpy as np

__all__ = [
    "AXIAL",
    "DIRECTIONS",
    "HULL_TRIANGLES",
    "MOVING",
    "MULTIPLICITY",
    "NON_AXIAL",
    "OPPOSITE",
    "ORDINATE_WEIGHTS",
    "Q",
    "REST",
    "STEP_LENGTHS",
    "UNIT_DIRECTIONS",
    "WEIGHTS",
    "barycentric_weights",
    "direction_index",
]

#: Number of lattice directions (D3Q19).
Q = 19
#: Index of the rest direction.
REST = 0
#: Indices of the axial directions (double weight).
AXIAL = tuple(range(1, 7))
#: Indices of the non-axial directions (single weight).
NON_AXIAL = tuple(range(7, 19))
#: Indices of the 18 moving directions (what the solver stores: f_0 is always 0 there).
MOVING = tuple(range(1, 19))


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


_TABLE = (
    (0, 0, 0),
    (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1),
    (1, 1, 0), (-1, -1, 0), (1, -1, 0), (-1, 1, 0),
    (1, 0, 1), (-1, 0, -1), (1, 0, -1), (-1, 0, 1),
    (0, 1, 1), (0, -1, -1), (0, 1, -1), (0, -1, 1),
)  # fmt: skip


def _projected_multiplicity() -> dict[tuple[int, int, int], int]:
    """geist2008 sec. 2.2: the 24 4D points (two nonzero ±1 entries), truncated to 3D."""
    counts: dict[tuple[int, int, int], int] = {}
    for a, b in itertools.combinations(range(4), 2):
        for sa, sb in itertools.product((1, -1), repeat=2):
            p = [0, 0, 0, 0]
            p[a], p[b] = sa, sb
            key = (p[0], p[1], p[2])
            counts[key] = counts.get(key, 0) + 1
    return counts


def _build() -> tuple[np.ndarray, np.ndarray]:
    proj = _projected_multiplicity()
    if sum(proj.values()) != 24 or len(proj) != 18:
        raise AssertionError("the 4D projection must give 24 points onto 18 directions")
    mult = np.array([proj.get(c, 0) for c in _TABLE], dtype=np.int64)
    if set(proj) != set(_TABLE[1:]) or mult[0] != 0:
        raise AssertionError("the direction table does not match the 4D projection")
    return np.array(_TABLE, dtype=np.int64), mult


_C, _M = _build()

#: (19, 3) int64 lattice vectors c_i, in the documented order.
DIRECTIONS = _frozen(_C)
#: (19,) int64: number of 4D points projecting onto c_i (0, then 2 x6, then 1 x12); sums to 24.
MULTIPLICITY = _frozen(_M)
#: (19,) float64: w_i = MULTIPLICITY / 24 (geist2008 eqs. (6)-(8)): 0, 1/12 x6, 1/24 x12; sum 1.
WEIGHTS = _frozen(_M / 24.0)
#: (19, 3) float64 unit directions n_i = c_i/|c_i| (row 0 is the zero vector).
UNIT_DIRECTIONS = _frozen(
    np.vstack([np.zeros(3), _C[1:] / np.sqrt((_C[1:] ** 2).sum(axis=1, keepdims=True))])
)
#: (19,) float64: |c_i|, the length of one step along c_i in lattice spacings: 0, 1 x6, sqrt(2) x12.
STEP_LENGTHS = _frozen(np.sqrt((_C**2).sum(axis=1).astype(np.float64)))
#: (19,) float64: degree-5 quadrature weights of the unit directions (module docstring): 0, 1/30 x6, 1/15 x12; sum 1.
ORDINATE_WEIGHTS = _frozen(np.concatenate([[0.0], np.full(6, 1.0 / 30.0), np.full(12, 1.0 / 15.0)]))
#: (19,) int64: index of -c_i (0 for rest).
OPPOSITE = _frozen(np.array([_TABLE.index(tuple(-np.array(c))) for c in _TABLE], dtype=np.int64))


def direction_index(c) -> int:
    """Index of the integer lattice vector ``c`` (e.g. ``(0, 0, -1)`` -> 6)."""
    key = tuple(int(v) for v in np.asarray(c).ravel())
    try:
        return _TABLE.index(key)
    except ValueError:
        raise ValueError(f"{key} is not a D3Q19 lattice vector; the 19 vectors are {_TABLE}") from None


def _hull() -> tuple[np.ndarray, np.ndarray]:
    from scipy.spatial import ConvexHull

    pts = UNIT_DIRECTIONS[1:]
    hull = ConvexHull(pts)
    tris = np.asarray(hull.simplices, dtype=np.int64) + 1  # lattice indices
    if tris.shape != (32, 3):  # steele2010 sec. 3.1: "a convex polyhedron, consisting of 32 faces"
        raise AssertionError(f"the hull of the 18 unit directions has {tris.shape[0]} triangles, expected 32")
    # orient each triangle counter-clockwise seen from outside, so the order is deterministic
    v = UNIT_DIRECTIONS[tris]
    flip = np.einsum("ij,ij->i", np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), v.sum(axis=1)) < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    tris = tris[np.lexsort(tris.T[::-1])]
    # columns of M are the vertices; inv(M) @ d gives d in vertex coordinates
    inv = np.linalg.inv(np.transpose(UNIT_DIRECTIONS[tris], (0, 2, 1)))
    return tris, inv


_TRIS, _TRI_INV = _hull()

#: (32, 3) int64 lattice indices (1..18) of the hull's triangles, outward counter-clockwise.
HULL_TRIANGLES = _frozen(_TRIS)
_TRI_INV = _frozen(_TRI_INV)


def barycentric_weights(direction) -> tuple[tuple[int, int, int], tuple[float, float, float]]:
    """The hull face hit by the ray from the origin along ``direction``, and the hit point's weights.

    steele2010 sec. 3.1: the sun ray intersects one of the 32 triangles formed
    by adjacent triples of unit lattice directions; its three directions and the
    barycentric coordinates of the intersection point select and weight the
    base solutions.

    Parameters
    ----------
    direction : (3,) array_like
        Any nonzero vector (need not be unit length). For relighting pass the
        direction the light *travels* (``-sun_dir``); see ``lb.relight``.

    Returns
    -------
    indices : 3 lattice indices in 1..18
    weights : 3 floats >= 0 summing to 1 (barycentric coordinates of the hit
        point, normalised as in steele2010). ``sum_k weights[k] *
        UNIT_DIRECTIONS[indices[k]]`` is the hit point, parallel to ``direction``.

    On an edge or vertex several faces are hit; the one whose smallest
    coordinate is largest is returned. The weights, scattered into a vector over
    the 18 directions, are continuous in ``direction`` (they agree on shared
    edges), so blended lighting does not jump as the sun moves.
    """
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(d))
    if not np.isfinite(n) or n == 0.0:
        raise ValueError(f"the direction must be a finite nonzero 3-vector, got {tuple(d)}")
    d = d / n
    # coordinates of d in each face's vertex basis: d = a n0 + b n1 + c n2
    coords = _TRI_INV @ d  # (32, 3)
    k = int(np.argmax(coords.min(axis=1)))
    lam = np.clip(coords[k], 0.0, None)
    # barycentric coordinates of the hit point d / (a + b + c) on the face
    w = lam / lam.sum()
    idx = tuple(int(i) for i in HULL_TRIANGLES[k])
    return idx, (float(w[0]), float(w[1]), float(w[2]))  # type: ignore[return-value]
