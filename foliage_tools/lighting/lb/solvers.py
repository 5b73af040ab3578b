"""The steady-state solvers of the lattice-Boltzmann lighting: plain sweeps, extrapolation, BiCGSTAB and ``solve``.

The package docstring (``lighting.lb``, "Steady state") describes them and what the residual means;
``memory_bytes`` is what a solve holds.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from foliage_tools.lighting.lb.directions import NQ
from foliage_tools.lighting.lb.kernels_field import _axpy_norm, _copy_field, _extrapolate, _p_update, _update_xr
from foliage_tools.lighting.lb.layout import _Operator, _safe_div
from foliage_tools.lighting.lb.problem import LBNumericalError, LBParams, LBProblem, LBResult

#: The package's logger: its messages keep the name ``foliage_tools.lighting.lb`` they had when it was one module.
log = logging.getLogger(__package__)


#: Largest per-sweep ratio q an extrapolation jump f + (f - f_prev) q / (1 - q) uses (a jump of at most 199x the
#: last change: a larger one, from a ratio that only looked settled, once overflowed float32 at 64^3 with 18 bases).
_MAX_EXTRAPOLATION_Q = 0.995


#: A solve stops when its residual, below ``STALL_EPS`` times the arithmetic's machine epsilon, has not reached a
#: new low in the last ``STALL_SWEEPS`` sweeps (against the ``STALL_SWEEPS`` before): it sits at the round-off floor
#: (float32: 1.6e-8 on a 24^3 dense sphere at sigma_a 0.1, 2.9e-8 at 0.001, flat from sweep ~100 on), and more
#: sweeps only spend time. A converging iteration, however slowly, keeps reaching new lows.
STALL_SWEEPS = 128
STALL_EPS = 1000.0


#: Ordered sweeps take a shorter window: each cuts the residual ~10x while converging, so 16 sweeps without a new
#: low is a stall (fp16 storage: the in-place rounded map settles ~3-6e-6 above the plain one's fixed point, and
#: ``--solver ordered`` ran 257 sweeps to find that with the plain window).
STALL_SWEEPS_ORDERED = 16


def _stalled(checks: list[tuple[int, float]], t: int, now: float, dtype: np.dtype, window: int = STALL_SWEEPS) -> bool:
    """Whether the measured residuals ``checks`` ((sweep, residual), in order) have stalled at sweep t."""
    if t < 2 * window or now >= STALL_EPS * float(np.finfo(dtype).eps):
        return False
    recent = [r for k, r in checks if k > t - window]
    before = [r for k, r in checks if t - 2 * window < k <= t - window]
    return bool(recent and before and min(recent) >= min(before))


def _stop_stalled(checks: list[tuple[int, float]], t: int, now: float, dtype: np.dtype, stalls: list[int] | None,
                  window: int = STALL_SWEEPS) -> bool:
    """``_stalled``, and if so say it and record sweep t in ``stalls``: whether the caller stops."""
    if not _stalled(checks, t, now, dtype, window):
        return False
    log.info("lb solve: the residual has stalled at %.2e (round-off) after %d sweeps; stopping", now, t)
    if stalls is not None:
        stalls.append(t)
    return True


#: Plain iteration runs its unmeasured sweeps as in-place pairs (``_Operator.sweep_pair``) only while the last
#: measured residual is at least this many machine epsilons of the arithmetic: the pairs collide by other arithmetic
#: than the measuring push sweeps (``kernels_collide._collide_sym``), ~1e-7 of the field apart per sweep in float32,
#: which near the round-off floor sets where the residual stalls (tree_small 48^3, ``--solver iterate --tolerance
#: 3e-8``: stalled at 5.3e-8 with pairs to the end, 3.0e-8 reached with push sweeps alone). 8 eps is 9.5e-7 in float32.
PAIR_MIN_RESIDUAL_EPS = 8.0


def _iterate(
    op: _Operator,
    f: np.ndarray,
    tol: float,
    budget: int,
    every: int,
    history: list,
    switch_after: int | None,
    *,
    extrapolate: bool = False,
    warmup: int | None = None,
    stalls: list[int] | None = None,
):
    """Plain sweeps from f, residual measured every ``every`` sweeps.

    Returns (f, sweeps, residuals (C, K), stopped_to_switch). Two consecutive unmeasured sweeps run in place
    (``_Operator.sweep_pair``, few right-hand sides), the rest as push sweeps into ``out``.

    The warm-up (default: the longest edge, at least 16 sweeps) is the time
    light needs to cross the grid, during which the residual falls slowly
    whatever the medium. After it:

    * ``switch_after``: stop when the contraction rate q measured over the
      last >= 8 sweeps predicts more than ``switch_after`` sweeps to go.
    * ``extrapolate``: measure the residual every sweep; when three consecutive
      per-sweep ratios q of a right-hand side agree to 1e-3, jump that
      right-hand side to ``f + (f - f_prev) q / (1 - q)``, the sum of the
      remaining geometric series of its slowest mode (Lyusternik
      extrapolation). The stopping test is unchanged, so a poor jump can only
      cost sweeps, never fake convergence.
    """
    out = _copy_field(f)
    res = np.full((op.C, op.K), np.inf)
    warm = max(16, op.nx, op.ny, op.nz) if warmup is None else warmup
    checks: list[tuple[int, float]] = []
    prev_res: np.ndarray | None = None
    ratios: list[np.ndarray] = []
    allowed = np.ones((op.C, op.K), bool)  # right-hand sides extrapolation may still jump
    jumped: np.ndarray | None = None  # residual just before the last jump
    pair_floor = PAIR_MIN_RESIDUAL_EPS * float(np.finfo(op.dtype).eps)

    def measured(t: int) -> bool:
        return (extrapolate and t >= warm) or t % every == 0 or t == budget

    t = 0
    while t < budget:
        t += 1
        every_sweep = extrapolate and t >= warm
        check = measured(t)
        if op.in_place and not check and t < budget and not measured(t + 1) and float(res.max()) >= pair_floor:
            op.sweep_pair(f)  # two unmeasured sweeps in place (the AA pattern): the same state, less memory traffic
            t += 1
            prev_res = None
            continue
        r = op.sweep(f, out, residual=check)
        f, out = out, f  # f = f_t, out = f_{t-1}
        if not check:
            prev_res = None
            continue
        assert r is not None  # swept with residual=check
        res = r
        if not np.all(np.isfinite(res)):
            raise LBNumericalError(
                "the lattice field became non-finite"
                + (" after an extrapolation jump; use the solver 'iterate' or 'bicgstab'" if extrapolate else "")
                + f" (sweep {t}). This is a bug if it happens with plain iteration: please report it with the input."
            )
        now = float(res.max())
        history.append(now)
        checks.append((t, now))
        if now < tol:
            return f, t, res, False
        if _stop_stalled(checks, t, now, op.dtype, stalls):
            return f, t, res, False
        if every_sweep:
            if jumped is not None:
                # a jump that did not lower the residual says the one-mode model is wrong here: stop jumping
                allowed &= ~(res > jumped)
                jumped = None
            if prev_res is not None:
                ratios = [*ratios[-2:], _safe_div(res, prev_res)]
            prev_res = res
            if len(ratios) == 3:
                q = np.stack(ratios)
                ok = allowed & (q.max(axis=0) < 1.0) & (q.min(axis=0) > 0.0) & (q.max(axis=0) - q.min(axis=0) < 1e-3)
                if ok.any():
                    qq = np.minimum(q[-1], _MAX_EXTRAPOLATION_Q)
                    _extrapolate(op.vec(f), op.vec(out), op.expand(np.where(ok, qq / (1.0 - qq), 0.0)))
                    ratios, prev_res, jumped = [], None, np.where(ok, res, np.inf)
        if switch_after is not None and t >= warm:
            back = [c for c in checks if c[0] <= t - 8]
            if back:
                t_prev, prev = back[-1]
                q1 = (now / prev) ** (1.0 / (t - t_prev)) if prev > 0 else 0.0
                if q1 >= 1.0 or math.log(tol / now) / math.log(q1) > switch_after:
                    return f, t, res, True
    return f, budget, res, False


#: ``auto`` runs at most this many sweeps (ordered ones and their measuring plain ones) before handing what is
#: left to plain sweeps and their switch to BiCGSTAB: tree_small's relightable and sun bakes converge in 7 at
#: 64^3 and 128^3, while a dense high-albedo medium's slow scattering modes converge no faster ordered.
AUTO_ORDERED_SWEEPS = 24

#: Ordered sweeps stop at this fraction of the tolerance: at the same plain-sweep residual an ordered iterate is
#: ~3.4x further from the fixed point than a plain one (tree_small, 64^3, 18 bases x RGB: per-leaf E_scattered
#: 0.23 % RMS from a 1e-7 solve at residual 1.5e-5, plain sweeps 0.035 % at 7.9e-6; 128^3 fp32: 0.18 % from
#: the plain solve when stopped at 9.7e-6), so a quarter keeps them as close as plain iteration at the tolerance.
ORDERED_TOLERANCE_FRACTION = 0.25


def _at_storage_floor(op: _Operator, f: np.ndarray, res: np.ndarray, checks: list[tuple[int, float]]) -> np.ndarray | None:
    """fp16 storage: the (C, K) rounding level (``_Operator.rounding``) of state f when the sweep that made it has
    reached it, else None. Reached: the residual made no new low (it is no longer contracting as a converging
    iteration does, which makes one at every measurement) and every right-hand side changed by no more than the
    sweep rounded it.

    Why that is the end of an fp16 solve: for the sweep g = T f + beta and its stored rounding rnd(g),
    (I - T)(f - f*) = f - g = (rnd(g) - g) - (rnd(g) - f), so the state's error is (I - T)^-1 applied to this
    sweep's rounding less its change. The rounding term is the storage's own: the fixed point of the rounded
    map, where the change is 0, carries one as large. With the change no larger than the rounding, the error
    bound is at most twice the fixed point's, and more sweeps only trade rounding noise (tree_small, 64^3, 18
    bases as beams: the change fell from 5.0e-5 to 7.6e-6 over 52 more sweeps while the unrounded residual
    |f - g| moved from 9.4e-5 to 9.0e-5 against a rounding of 8.8e-5, and the per-leaf result did not move).
    """
    if not checks or float(res.max()) < min(r for _, r in checks):
        return None
    return _within_rounding(op, f, res)


def _within_rounding(op: _Operator, f: np.ndarray, res: np.ndarray) -> np.ndarray | None:
    """fp16 storage: the (C, K) rounding level of state f if no right-hand side's residual exceeds it, else None."""
    if op.storage != np.uint16:
        return None
    level = op.rounding(f)
    return level if bool(np.all(res <= level)) else None


def _stop_at_rounding(level: np.ndarray | None, res: np.ndarray, n: int, floor: list[float] | None) -> bool:
    """Whether a solve stops at the storage's rounding ``level`` (``_at_storage_floor`` or ``_within_rounding``);
    if so say it and record the level in ``floor``."""
    if level is None:
        return False
    log.info("lb solve: the fp16 state changes by %.2e per sweep, no more than its rounding (%.2e), and no longer "
             "falls: converged to the storage's precision after %d sweeps", float(res.max()), float(level.max()), n)
    if floor is not None:
        floor.append(float(level.max()))
    return True


def _ordered(op: _Operator, f: np.ndarray, tol: float, budget: int, history: list, stalls: list[int] | None = None,
             floor: list[float] | None = None):
    """In-place ordered sweeps (``kernels_ordered``), forward and backward in turn, each from the second on
    followed by a plain sweep that measures the residual (the same residual as plain iteration's) and is kept
    as the next iterate. Returns (f, sweeps, residuals (C, K)); a sweep of either kind counts as one.

    Why: plain sweeps move light one node per sweep, so from the unscattered start the relightable bake's
    residual falls slowly until the once-scattered light has left the grid (tree_small: 64 sweeps to 1e-5 at
    64^3, 128 at 128^3), whereas an ordered sweep carries half the directions across the whole grid and the
    residual falls by about an order of magnitude per sweep whatever the grid's size (``kernels_ordered``).

    With fp16 storage they also stop at the storage's rounding level (``_at_storage_floor``), appended to
    ``floor`` (its largest relative rms over the right-hand sides).
    """
    out = _copy_field(f)  # the sweeps never write inflow slots: both fields hold the boundary values there
    res = np.full((op.C, op.K), np.inf)
    n = 0
    passes = 0
    checks: list[tuple[int, float]] = []
    while n < budget:
        paired = n + 2 <= budget  # room for an ordered sweep and the plain one that measures it
        if paired:
            op.ordered_sweep(f, forward=passes % 2 == 0)
            passes += 1
            n += 1
            if passes < 2 and n + 2 <= budget:  # measure once both orders have run, or where the budget ends
                continue
        r = op.sweep(f, out, residual=True)
        assert r is not None  # swept with residual=True
        f, out = out, f
        n += 1
        res = r
        history.append(float(res.max()))
        if not np.all(np.isfinite(res)):
            raise LBNumericalError(f"the lattice field became non-finite (ordered sweeps, sweep {n}); please report it "
                                   "with the input.")
        if res.max() < tol * ORDERED_TOLERANCE_FRACTION:
            break
        # (a lone plain sweep where the budget ends cannot make the ordered sweeps' new low: not judged)
        if paired and _stop_at_rounding(_at_storage_floor(op, f, res, checks), res, n, floor):
            break
        checks.append((n, float(res.max())))
        if _stop_stalled(checks, n, float(res.max()), op.dtype, stalls, STALL_SWEEPS_ORDERED):
            break
    return f, n, res


def _bicgstab(op: _Operator, x: np.ndarray, tol: float, budget: int, history: list):
    """BiCGSTAB on (I - T) x = beta for all right-hand sides in lock-step (van der Vorst 1992).

    ``x`` holds beta in its inflow slots; every Krylov vector has zero inflow
    slots, so the kernel (which never writes inflow slots) applies T to them
    directly. Returns (x, sweeps, converged_flags (C, K)).
    """
    C, K = op.C, op.K
    sweeps = 0
    r = op.zeros()
    op.sweep(x, r, residual=False)  # T x (+ propagation of the inflow held in x)
    sweeps += 1
    r -= x
    op.set_inflow(r, zero=True)  # r = T x + beta - x: zero in the inflow slots
    rhat = r.copy()
    p = op.zeros()
    v = op.zeros()
    t = op.zeros()
    ones = np.ones((C, K))
    rho_old, alpha, omega_ = ones.copy(), ones.copy(), ones.copy()
    rr = op.dot(r, r)
    xx = op.dot(x, x)
    hr = rr.copy()
    done = np.sqrt(_safe_div(rr, xx)) < tol
    V = op.vec
    pa, pb, pc = op._parts
    while sweeps + 2 <= budget and not done.all():
        rho_new = hr
        beta = _safe_div(rho_new, rho_old) * _safe_div(alpha, omega_)
        beta[done] = 0.0
        _p_update(V(p), V(r), V(v), op.expand(beta), op.expand(omega_))
        hv, _ = op.apply(p, v, rhat)  # v = (I - T) p, rhat . v
        sweeps += 1
        alpha = _safe_div(rho_new, hv)
        alpha[done] = 0.0
        _axpy_norm(V(r), op.expand(-alpha), V(v), pa)  # r <- s = r - alpha v
        ts, tt = op.apply(r, t, r)  # t = (I - T) s, t . s, t . t
        sweeps += 1
        omega_ = _safe_div(ts, tt)
        omega_[done] = 0.0
        # x <- x + alpha p + omega s, r <- s - omega t
        _update_xr(V(x), op.expand(alpha), V(p), op.expand(omega_), V(r), V(t), V(rhat), pa, pb, pc)
        xx, rr, hr = op.reduce(pa), op.reduce(pb), op.reduce(pc)
        rho_old = rho_new
        res = np.sqrt(_safe_div(rr, xx))
        done |= res < tol
        history.append(float(res.max()))
        # breakdown (rhat . r ~ 0 or omega = 0): restart that right-hand side with rhat = r
        bad = ~done & ((np.abs(hr) <= 1e-12 * rr) | (omega_ == 0.0))
        for c, k in zip(*np.nonzero(bad)):
            rhat[:, :, :, c, :, k] = r[:, :, :, c, :, k]
            p[:, :, :, c, :, k] = 0.0
            v[:, :, :, c, :, k] = 0.0
            hr[c, k] = rr[c, k]
            rho_old[c, k] = alpha[c, k] = omega_[c, k] = 1.0
    return x, sweeps, done


# LBParams is a frozen dataclass: one shared default is safe (ruff sees that only within its own module)
def solve(problem: LBProblem, params: LBParams = LBParams()) -> LBResult:  # noqa: B008
    """Steady state of the lattice for every boundary condition and channel of ``problem``.

    Returns energy density u = sum_i f_i per node (and f if asked), the
    residual, sweeps, timing and the per-sweep energy balance; see the package
    docstring (``lighting.lb``) for the solvers and units.
    """
    t0 = time.perf_counter()
    op = _Operator(problem, params.dtype, params.storage, params.beam_outputs)
    nrhs = op.C * op.K
    tol = params.tolerance
    history: list[float] = []
    f = op.unscattered(problem) if params.initial == "unscattered" else op.initial()
    once = None
    if op.beams is not None and params.beam_outputs:  # the lattice's once-scattered light: the unscattered start for a beam
        once = op.energy(f if params.initial == "unscattered" else op.unscattered(problem))
    sweeps = 0
    used: list[str] = []
    stalls: list[int] = []  # sweeps at which a phase stopped because its residual stalled
    floor: list[float] = []  # fp16: the rounding level at which the solve stopped (``_at_storage_floor``)
    t_loop = time.perf_counter()
    res = np.full((op.C, op.K), np.inf)
    switched = False
    if params.solver == "auto":  # ordered sweeps first: most bakes converge there in a handful (``_ordered``)
        f, sweeps, res = _ordered(op, f, tol, min(AUTO_ORDERED_SWEEPS, params.max_sweeps), history, floor=floor)
        # (a stall here is not final: auto hands what is left to plain sweeps; the fp16 storage's floor is)
        used.append("ordered")
    if params.solver in ("iterate", "extrapolate") or (params.solver == "auto" and not res.max() < tol and not floor
                                                       and sweeps < params.max_sweeps):
        # auto: what ordered sweeps left (a strongly scattering medium's slow modes) goes to plain sweeps,
        # which switch to BiCGSTAB or extrapolation when they too are slow
        switch = params.switch_sweeps if params.solver == "auto" else None
        extra = params.solver == "extrapolate"
        f, n, res, switched = _iterate(op, f, tol, params.max_sweeps - sweeps, params.check_every, history, switch,
                                       extrapolate=extra, warmup=0 if sweeps else None, stalls=stalls)
        sweeps += n
        used.append("extrapolate" if extra else "iterate")
    if params.solver == "ordered":
        f, sweeps, res = _ordered(op, f, tol, params.max_sweeps, history, stalls, floor)
        used.append("ordered")
    krylov = params.solver == "bicgstab"
    if switched:  # auto, and plain iteration is slow
        krylov = 6 * op.field_bytes <= params.memory_limit and params.storage == "fp32"
        log.info("lb solve: plain sweeps converge slowly after %d (residual %.2e); switching to %s", sweeps,
                 float(res.max()), "BiCGSTAB" if krylov else "extrapolated sweeps (BiCGSTAB would not fit or needs fp32)")
        if not krylov:
            f, n, res, _ = _iterate(
                op, f, tol, params.max_sweeps - sweeps, params.check_every, history, None, extrapolate=True, warmup=0,
                stalls=stalls,
            )
            sweeps += n
            used.append("extrapolate")
    if krylov:
        for _attempt in range(4):
            budget = params.max_sweeps - sweeps - 1
            if budget < 3:  # no room for a step (and the plain sweep that measures it)
                break
            if "bicgstab" not in used:
                used.append("bicgstab")
            f, n, _ = _bicgstab(op, f, tol, budget, history)
            sweeps += n
            # the reported residual is always that of a plain sweep from the result
            out = f.copy()
            res = op.sweep(f, out, residual=True)
            sweeps += 1
            f = out
            if res.max() < tol:
                break
        if not np.all(np.isfinite(res)):  # max_sweeps leaves no room for a BiCGSTAB step: plain sweeps
            f, n, res, _ = _iterate(op, f, tol, max(params.max_sweeps - sweeps, 1), params.check_every, history, None,
                                    stalls=stalls)
            sweeps += n
            used.append("iterate")
    if stalls and not floor and not res.max() < tol:
        # plain sweeps stalled (``_stalled``: no longer falling): on fp16 storage within its rounding that is the
        # same end as ordered sweeps reach (``_at_storage_floor``), so the same verdict
        _stop_at_rounding(_within_rounding(op, f, res), res, sweeps, floor)
    loop_seconds = time.perf_counter() - t_loop
    log.debug("lb solve: %s nodes x %d rhs, %s, %d sweeps, residual %.2e (tolerance %.1e), %.2f s", f"{op.nodes:,}", nrhs,
              "+".join(used), sweeps, float(res.max()), tol, loop_seconds)
    if not np.all(np.isfinite(res)):
        raise LBNumericalError(f"the lattice solve ended with a non-finite residual (solver {'+'.join(used)}); "
                               "use the solver 'iterate', and please report the input.")
    inflow, outflow, absorbed = op.balance(f)
    energy = op.energy(f)  # (nx, ny, nz, K, C)
    if op.beams is not None:  # a beam's lattice field is its scattered light: add the exact unscattered beam
        if op.beams.direct is not None:  # (beam_outputs False: the lattice's scattered light alone)
            energy += op.beams.direct.astype(energy.dtype)
    full = op.from_row(f) if params.keep_f else None
    return LBResult(
        energy_density=energy,
        f=full,
        boundaries=tuple(b.name for b in problem.boundaries),
        iterations=sweeps,
        residual=float(res.max()),
        residuals=res.T.copy(),
        converged=bool(res.max() < tol) or bool(floor),
        stalled=bool(stalls) and not res.max() < tol and not floor,
        rounding_level=floor[-1] if floor else None,
        seconds=time.perf_counter() - t0,
        solver="+".join(used),
        mlups=op.nodes * nrhs * sweeps / max(loop_seconds, 1e-12) / 1e6,
        nrhs=nrhs,
        inflow=inflow.T.copy(),
        outflow=outflow.T.copy(),
        absorbed=absorbed.T.copy(),
        history=tuple(history),
        beam_direct=None if op.beams is None else op.beams.direct,
        beam_power=None if op.beams is None else op.beams.power,
        once_scattered=once,
    )


#: Fields of 18 float32 directions (72 bytes per node and right-hand side) plain iteration holds: the
#: state and its update, plus the outputs and temporaries of the bake (~0.3 field).
PLAIN_ITERATION_FIELDS = 2.3

#: The same for a relightable bake (``--bases all``, the 18 bases x RGB), measured: its peak resident memory is
#: 2.02-2.06 float32 fields at 64^3-128^3 with fp32 storage, the same 2 fields' worth of state plus 0.07-0.12 field
#: with fp16 (``benchmarks/bench_lb_storage.py``, 2026-12-04; the process itself holds ~0.3 GB of that). Its
#: outputs (1/18 field each) come after the solve has let its second field go. 2.1 leaves a little margin.
RELIGHTABLE_ITERATION_FIELDS = 2.1

#: Fields a solve of beams with ``LBParams.beam_outputs`` False adds: the beams' power in float32, in
#: ``BeamFields`` until the source is built and in the run layout, each 1/18 of a field.
BEAM_SOURCE_FIELDS = 0.1


def memory_bytes(shape, nrhs: int, fields: float = PLAIN_ITERATION_FIELDS, value_bytes: int = 4) -> float:
    """Bytes a solve on a grid of ``shape`` with ``nrhs`` right-hand sides holds (``fields`` fields of
    ``value_bytes`` per density: 4 for ``storage="fp32"``, 2 for ``"fp16"``)."""
    return float(np.prod(shape)) * nrhs * NQ * value_bytes * fields
