"""The kernels the monitor's hot path runs on, chosen by name here and nowhere else.

- ``python``: the numpy reference (canfdi.core.residuals.fir_rows,
  canfdi.core.detect.change_point_block, canfdi.bus.dbc.BusMap.decode_frames_reference,
  canfdi.bus.timegate.TimeGate.apply_reference, and a diagnoser's own
  ``information_reference``, ``solve_reference`` and ``decide_reference``: the parity
  diagnosis' regressors and sums, their solution, and the decision at each sample).
- ``c``: the C core (canfdi/_c, built as canfdi._ckernel by the package's own build where a
  compiler exists): the same functions over the same arrays. The detector's statistics are
  numpy's bit for bit (the same closed form, op for op); the residuals agree to rounding
  (numpy's BLAS may order or fuse a row's sum otherwise), and so do a diagnosis' information
  sums (einsum's order); a diagnosis' decisions are numpy's but where a test sits within
  rounding of its bound; the frame decode's statuses,
  slots, counters and values and the time gate's times, drops and steps are numpy's to the
  bit.

A diagnoser that has block forms to speed up takes a kernel by its ``use_kernel`` method
(`Kernel.use_on` calls it where there is one), which installs the kernel's functions on its
residual bank and detectors (`Kernel.install`). The name is resolved (`resolve`,
canfdi.core.kernelchoice) as ``--kernel``, else CANFDI_KERNEL, else ``c`` where built; a
library caller that names none (Monitor, evaluate) gets the same, so a live run and its replay
give the same numbers.

Examples
--------
>>> get("python").name, "python" in available()
('python', True)
>>> try:
...     get("fortran")
... except KernelError as exc:
...     print(exc)
kernel: expected one of c, python, got 'fortran'
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from canfdi.core.detect import ChangePointBlock, change_point_block
from canfdi.core.identify import InformationSums, RlsSolution, RlsState
from canfdi.core.kernelchoice import ENV, KernelError, choose
from canfdi.core.residuals import fir_rows

__all__ = ["ENV", "Kernel", "KernelError", "available", "get", "resolve"]

try:  # built by setup.py where a compiler was found at install; optional by design
    from canfdi import _ckernel
except ImportError:  # pragma: no cover - exercised by the no-compiler install check
    _ckernel = None


@dataclass(frozen=True)
class Kernel:
    """One kernel: its name and its block functions (the signatures of the numpy ones).

    Examples
    --------
    >>> from canfdi.core.detect import ChangePointDetector
    >>> det = ChangePointDetector(1, 0.5, [4.0])
    >>> get("python").install(detectors=(det,))
    >>> det.update_block(np.arange(3), np.array([[1.0], [3.0], [3.0]])).done
    2
    """

    name: str
    fir_rows: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    change_point_block: Callable[..., ChangePointBlock]
    decode_frames: Callable[[Any, Any], tuple]
    gate_apply: Callable[[Any, np.ndarray, np.ndarray], tuple]
    latest_values: Callable[..., np.ndarray] | None
    counter_machine: Callable[..., tuple] | None
    information_block: Callable[..., InformationSums] | None = None
    information_solve: Callable[[RlsState], RlsSolution] | None = None
    decide: Callable[..., Any] | None = None

    def install(self, *, bank: Any = None, detectors: tuple[Any, ...] = (),
                bus_map: Any = None, gate: Any = None, clock: Any = None,
                fits: Any = None) -> None:
        """Make ``bank`` (a ResidualBank), ``detectors`` (ChangePointDetector), ``bus_map``
        (canfdi.bus.dbc.BusMap: its frame decode), ``gate`` (canfdi.bus.timegate.TimeGate),
        ``clock`` (a sample clock: a latest-value clock's samples, the counter clock's
        state machine) and ``fits`` (a diagnosis' fits in information form: its regressors
        and sums, ``information``, their solution, ``solve``, and the decision over them,
        ``decide``, beside their numpy ``information_reference``, ``solve_reference`` and
        ``decide_reference``) run on this kernel."""
        if bank is not None:
            bank.fir_rows = self.fir_rows
        for det in detectors:
            det.block = self.change_point_block
        if bus_map is not None:
            bus_map.decoder = self.decode_frames
        if gate is not None:
            gate.block = self.gate_apply
        if clock is not None and hasattr(clock, "latest_values"):
            clock.latest_values = self.latest_values or clock.latest_values_reference
        if clock is not None and hasattr(clock, "machine"):
            clock.machine = self.counter_machine
        if fits is not None:
            fits.information = self.information_block or fits.information_reference
            fits.solve = self.information_solve or fits.solve_reference
            fits.decide = self.decide or fits.decide_reference

    def use_on(self, diagnoser: Any) -> Any:
        """``diagnoser`` (a method's) with its block forms on this kernel, where it has any
        to speed up (its ``use_kernel``); returned for chaining."""
        use = getattr(diagnoser, "use_kernel", None)
        if use is not None:
            use(self)
        return diagnoser


def _c_fir_rows(x: np.ndarray, blocks: np.ndarray, uses: np.ndarray) -> np.ndarray:
    """fir_rows in C (cfdi_fir_block)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    S1, width, m = blocks.shape
    if x.ndim != 2 or x.shape[1] != width:
        raise ValueError(f"x: expected shape (N, {width}), got {x.shape}")
    out = np.empty((len(x) - S1 + 1, m))
    _ckernel.fir_block(x, len(x), width, np.ascontiguousarray(blocks, dtype=np.float64),
                       _as_u8(uses), S1 - 1, m, out)
    return out


def _as_u8(uses: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(uses != 0, dtype=np.uint8)


def _c_change_point_block(k: np.ndarray, x: np.ndarray, delta: np.ndarray, h: np.ndarray,
                          state: np.ndarray, last_zero: np.ndarray) -> ChangePointBlock:
    """change_point_block in C (cfdi_ph_block)."""
    k = np.ascontiguousarray(k, dtype=np.int64)
    x = np.ascontiguousarray(x, dtype=np.float64)
    n, c = x.shape
    if k.shape != (n,):
        raise ValueError(f"k: expected shape ({n},), got {k.shape}")
    st = np.array(state, dtype=np.float64, order="C").reshape(c, 2)
    lz = np.array(last_zero, dtype=np.int64, order="C").reshape(c, 2)
    g_up, g_down = np.empty((n, c)), np.empty((n, c))
    alarm = np.zeros(c, dtype=np.int8)
    done = _ckernel.ph_block(k, x, n, c, np.ascontiguousarray(delta, dtype=np.float64),
                             np.ascontiguousarray(h, dtype=np.float64), st, lz, g_up, g_down,
                             alarm)
    rows = min(done + 1, n)
    return ChangePointBlock(done, g_up[:rows], g_down[:rows], alarm, st, lz)


def _py_decode_frames(bus_map: Any, block: Any) -> tuple:
    """A BusMap's frame decode in numpy (BusMap.decode_frames_reference)."""
    return bus_map.decode_frames_reference(block)


_NO_LONG = np.zeros((0, 64), dtype=np.uint8)


def _c_decode_frames(bus_map: Any, block: Any) -> tuple:
    """A BusMap's frame decode in C (cfdi_decode_block) from its tables (BusMap.c_tables);
    a map beyond the C core's bounds (a slot of over 64 compiled signals) decodes in numpy."""
    tables = bus_map.c_tables()
    if not tables.fits:
        return bus_map.decode_frames_reference(block)
    n = block.size
    status = np.empty(n, dtype=np.int8)
    slot = np.empty(n, dtype=np.int16)
    values = np.empty((n, tables.width))
    counters = np.empty(n, dtype=np.int64)
    long_row = np.full(n, -1, dtype=np.int32)
    longdata = _NO_LONG
    if block.long:
        rows = sorted(block.long)
        longdata = np.zeros((len(rows), 64), dtype=np.uint8)
        for i, row in enumerate(rows):
            data = block.long[row][:64]
            longdata[i, :len(data)] = np.frombuffer(data, dtype=np.uint8)
            long_row[row] = i
    _ckernel.decode_block(tables.c_args, n, np.ascontiguousarray(block.id, dtype=np.uint32),
                          np.ascontiguousarray(block.dlc, dtype=np.uint8),
                          np.ascontiguousarray(block.flags, dtype=np.uint8),
                          np.ascontiguousarray(block.data, dtype=np.uint8), long_row, longdata,
                          len(longdata), status, slot, values, counters)
    return status, slot, values, counters


def _py_gate_apply(gate: Any, t: np.ndarray, rows: np.ndarray) -> tuple:
    """A TimeGate's block form in numpy (TimeGate.apply_reference)."""
    return gate.apply_reference(t, rows)


_INT64 = (-(1 << 63), (1 << 63) - 1)


def _c_gate_apply(gate: Any, t: np.ndarray, rows: np.ndarray) -> tuple:
    """A TimeGate's block form in C (cfdi_gate_block), from the gate's state and back into
    it. The C stops where a time, offset or reference nears int64's ends; the reference takes
    the rest of the block from there, with Python's integers (as it takes a gate whose state
    no longer fits int64 at all)."""
    count, first, last = gate.chain
    state = [gate.ref is not None, gate.ref or 0, gate.offset, count, first, last, gate.jumps]
    n = len(rows)
    if not n or not all(_INT64[0] <= int(v) <= _INT64[1] for v in state) \
            or not 0 < gate.bound < 1 << 61:
        return gate.apply_reference(t, rows)
    st = np.array(state, dtype=np.int64)
    times = np.ascontiguousarray(t, dtype=np.int64)
    out = times.copy()
    at = np.ascontiguousarray(rows, dtype=np.int64)
    dropped = np.empty(n, dtype=np.int64)
    steps = np.empty((n, 2), dtype=np.int64)
    n_dropped, n_steps, done = _ckernel.gate_block(st, gate.bound, gate.confirm, times,
                                                   len(times), at, n, out, dropped, steps)
    gate.ref = int(st[1]) if st[0] else None
    gate.offset = int(st[2])
    gate.chain = (int(st[3]), int(st[4]), int(st[5]))
    gate.jumps = int(st[6])
    gate.steps.extend((int(a), int(b)) for a, b in steps[:n_steps].tolist())
    drops = dropped[:n_dropped].astype(np.intp)
    if done < n:
        rest = rows[done:]
        later, rest_dropped = gate.apply_reference(times, rest)
        out[rest] = later[rest]
        drops = np.concatenate([drops, rest_dropped + done])
    return out, drops


def _c_latest_values(ok: np.ndarray, slot: np.ndarray, values: np.ndarray, t: np.ndarray,
                     instants: np.ndarray, upto: np.ndarray, dest: np.ndarray,
                     max_age_ns: float, value: np.ndarray, time: np.ndarray) -> np.ndarray:
    """canfdi.bus.clock.latest_values in C (cfdi_latest_block); ``value`` and ``time`` are
    the clock's own arrays, updated in place."""
    values = np.ascontiguousarray(values, dtype=np.float64)
    n_samples, width = len(instants), len(value)
    out = np.empty((n_samples, width))
    dest = np.ascontiguousarray(dest, dtype=np.int64)
    _ckernel.latest_block(np.ascontiguousarray(ok, dtype=np.int64), len(ok),
                          np.ascontiguousarray(slot, dtype=np.int16), len(slot), values,
                          values.shape[1] if values.ndim == 2 else 0,
                          np.ascontiguousarray(t, dtype=np.int64), dest, dest.shape[0],
                          dest.shape[1], np.ascontiguousarray(instants, dtype=np.int64),
                          np.ascontiguousarray(upto, dtype=np.int64), n_samples,
                          float(max_age_ns), value, time, width, out)
    return out


def _c_counter_machine(state: np.ndarray, buffer: np.ndarray, rows: np.ndarray,
                       slots: np.ndarray, counters: np.ndarray, times: np.ndarray,
                       values: np.ndarray, status: np.ndarray, dest: np.ndarray, mod: int,
                       dt_ns: float, slack: float) -> tuple:
    """The counter clock's state machine over a run of frames in C (cfdi_counter_run):
    ``state`` and ``buffer`` (the assembler's, as arrays) and ``status`` updated; returns
    ((ks, done, gaps, samples) of the samples delivered, frames used)."""
    n = len(rows)
    width = len(buffer)
    values = np.ascontiguousarray(values, dtype=np.float64)
    ks, done, gaps = (np.empty(2 * n, dtype=np.int64) for _ in range(3))
    samples = np.empty((2 * n, width))
    dest = np.ascontiguousarray(dest, dtype=np.int64)
    n_out, used = _ckernel.counter_run(
        state, buffer, width, np.ascontiguousarray(rows, dtype=np.int64),
        np.ascontiguousarray(slots, dtype=np.int64),
        np.ascontiguousarray(counters, dtype=np.int64),
        np.ascontiguousarray(times, dtype=np.int64), n, values, values.shape[0],
        values.shape[1], dest, dest.shape[0], dest.shape[1], int(mod), float(dt_ns),
        float(slack), status, len(status), ks, done, gaps, samples)
    return (ks[:n_out], done[:n_out], gaps[:n_out], samples[:n_out]), used


def info_work(m: int, d: int, S: int, p: int, H: int) -> int:
    """cfdi.h's CFDI_INFO_WORK with its bound on the distinct columns (H d): the reals of
    cfdi_info_block's scratch."""
    nc = H * d
    return ((3 * m + 2 * d + 1) * d + (S + 1) * p + H * (2 * d * d + d) + 3 * m * nc
            + 2 * nc * nc + nc + (2 * nc * nc + nc) // 4 + 1)


def _c_information_block(bank: Any, hypotheses: Any, columns: np.ndarray, d: int,
                         onsets: np.ndarray, k: np.ndarray, u_windows: np.ndarray,
                         rn: np.ndarray, gamma: np.ndarray) -> InformationSums:
    """A diagnosis' regressors and information sums in C (cfdi_info_block), from the
    hypotheses' ``columns`` (canfdi.methods.parity.hypotheses.regressor_columns)."""
    del hypotheses  # numpy's form of ``columns``
    Gz = np.ascontiguousarray(bank.Gz, dtype=np.float64)
    Gu = np.ascontiguousarray(bank.Gu, dtype=np.float64)
    (q, m, S1), p = Gz.shape, Gu.shape[0]
    H, K = len(columns), len(onsets)
    n = len(k)
    J, meat = np.zeros((H, K, d, d)), np.zeros((H, K, d, d))
    h, rr, n_eq = np.zeros((H, K, d)), np.zeros(1), np.zeros(1, dtype=np.int64)
    _ckernel.info_block(q, p, m, S1 - 1, Gz, Gu, np.ascontiguousarray(bank.sigma,
                                                                     dtype=np.float64),
                        H, d, np.ascontiguousarray(columns, dtype=np.int32), K,
                        np.ascontiguousarray(onsets, dtype=np.int64), n,
                        np.ascontiguousarray(k, dtype=np.int64),
                        np.ascontiguousarray(u_windows, dtype=np.float64).reshape(n, S1, p),
                        np.ascontiguousarray(rn, dtype=np.float64).reshape(n, m),
                        np.ascontiguousarray(gamma, dtype=np.float64), J, h, meat, rr, n_eq,
                        np.empty(info_work(m, d, S1 - 1, p, H)))
    return InformationSums(J=J, h=h, rr=rr[0], n_eq=int(n_eq[0]), meat=meat)


def _c_information_solve(state: RlsState) -> RlsSolution:
    """canfdi.core.identify.rls_solve in C (cfdi_info_solve): every estimator of the state
    (any batch shape) solved by LU with partial pivoting; numpy.linalg.LinAlgError for a
    singular information matrix, as numpy's solve raises."""
    d = state.d
    batch = state.h.shape[:-1]
    count = int(np.prod(batch, dtype=np.int64))
    J = np.ascontiguousarray(state.J, dtype=np.float64).reshape(count, d, d)
    h = np.ascontiguousarray(state.h, dtype=np.float64).reshape(count, d)
    rr = np.ascontiguousarray(np.broadcast_to(state.rr, batch), dtype=np.float64).reshape(count)
    theta, P, cost = np.empty((count, d)), np.empty((count, d, d)), np.empty(count)
    status = _ckernel.info_solve(count, d, J, h, rr, theta, P, cost, np.empty((d, d)),
                                 np.empty(d, dtype=np.uintp))
    if status != 0:
        raise np.linalg.LinAlgError("Singular matrix")
    return RlsSolution(theta=theta.reshape(*batch, d), P=P.reshape(*batch, d, d),
                       cost=cost.reshape(batch), dof=max(state.n_eq - d, 1))


def _c_decide(table: Any, settings: Any, fit: RlsSolution, rr: np.ndarray, n_eq: int,
              meat: np.ndarray, u_abs: np.ndarray, n_u: np.ndarray, units: np.ndarray,
              leftover: np.ndarray, since: int, named: bool) -> tuple:
    """canfdi.methods.parity.decide.decide_reference in C (cfdi_decide): the fields of its
    Decision, in their order."""
    theta = np.ascontiguousarray(fit.theta, dtype=np.float64)
    H, K, d = theta.shape
    p = len(u_abs)
    best_onset, order = np.empty(H, dtype=np.int64), np.empty(H, dtype=np.int64)
    cost_h, near, result = np.empty(H), np.empty(H, dtype=np.uint8), np.empty(5, dtype=np.int32)
    scale = _ckernel.decide(
        H, d, p, K, np.ascontiguousarray(table.kind, dtype=np.int8),
        np.ascontiguousarray(table.index, dtype=np.int32),
        np.ascontiguousarray(table.n_params, dtype=np.int32),
        np.ascontiguousarray(table.full, dtype=np.int32),
        np.ascontiguousarray(table.name_key, dtype=np.int64),
        np.ascontiguousarray(table.twins, dtype=np.uint8),
        np.ascontiguousarray(table.penalty, dtype=np.float64), int(settings.max_samples),
        np.array([settings.isolation_margin, settings.settle_rel_std, settings.settle_noise,
                  settings.max_fit_variance], dtype=np.float64), theta,
        np.ascontiguousarray(fit.P, dtype=np.float64),
        np.ascontiguousarray(np.broadcast_to(fit.cost, (H, K)), dtype=np.float64),
        np.ascontiguousarray(np.broadcast_to(rr, (H, K)), dtype=np.float64),
        np.ascontiguousarray(meat, dtype=np.float64),
        np.ascontiguousarray(u_abs, dtype=np.float64), np.ascontiguousarray(n_u, dtype=np.float64),
        np.ascontiguousarray(units, dtype=np.float64),
        np.ascontiguousarray(leftover, dtype=np.int32), int(n_eq), int(since), int(bool(named)),
        best_onset, cost_h, order, near, result)
    action, best, kb, size_known, form_known = (int(v) for v in result)
    return (action, best, kb, scale, bool(size_known), bool(form_known), best_onset, cost_h,
            order, near.astype(bool))


_KERNELS: dict[str, Kernel | None] = {
    "c": None if _ckernel is None else Kernel("c", _c_fir_rows, _c_change_point_block,
                                              _c_decode_frames, _c_gate_apply,
                                              _c_latest_values, _c_counter_machine,
                                              _c_information_block, _c_information_solve,
                                              _c_decide),
    "python": Kernel("python", fir_rows, change_point_block, _py_decode_frames,
                     _py_gate_apply, None, None),
}


def available() -> list[str]:
    """The kernels built in this install, by name."""
    return sorted(name for name, k in _KERNELS.items() if k is not None)


def get(name: str) -> Kernel:
    """The kernel ``name``; KernelError when it is none, or not built here."""
    kernel = _KERNELS.get(choose(name, env={}))
    if kernel is None:  # built, yet it did not load (a broken extension)
        raise KernelError(f"kernel {name}: canfdi._ckernel does not load here; use "
                          f"--kernel python")
    return kernel


def resolve(choice: str | None = None, env: Mapping[str, str] | None = None) -> Kernel:
    """The kernel a command runs on (canfdi.core.kernelchoice.choose): ``choice`` (its
    --kernel), else the environment's CANFDI_KERNEL, else ``c`` where built, else
    ``python``."""
    return get(choose(choice, env))
