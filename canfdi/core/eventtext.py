"""A diagnosis as one line of text: what the CLI prints and the log's ``/canfdi/log`` holds.

>>> from canfdi.core.records import FaultEvent
>>> event_line(FaultEvent("accepted", 3200, 0, target="sensor", index=1, name="i_a",
...                       estimates={"bias": 1.001}, onset_sample=3000), dt=0.01)
'  t=   32.00 s  k=3200    FAULT      sensor 1 (i_a): bias=1.001, onset k=3000'
"""

from __future__ import annotations

from canfdi.core.records import FaultEvent

__all__ = ["estimates_text", "event_level", "event_line"]

_LEVELS = {"detected": "info", "matched": "info", "taught": "info", "quiet": "info"}
_UNDECIDED = {"form": "scale or offset (waiting for the command to move)",
              "size": "its size (the estimate still settling)"}


def event_level(event: FaultEvent) -> str:
    """How loud a diagnosis is, as a log level: a change detected, noise back at its value or
    quieter than configured, or the noise taught are news ("info"); a fault named or accepted,
    a refinement, an unexplained change, a noise mismatch or a failed teach-in need someone's
    attention ("warning")."""
    return _LEVELS.get(event.kind, "warning")


def estimates_text(estimates: dict) -> str:
    """``eta=0.9, lambda=1.2``: estimates as the lines show them."""
    return ", ".join(f"{k}={v:.4g}" for k, v in estimates.items())


def event_line(event: FaultEvent, dt: float, show_drive: bool = False) -> str:
    """One line per diagnosis, as it happens (with the drive's name when ``show_drive``: a
    monitor of several drives)."""
    t = event.sample * dt
    who = f"[{event.drive}] " if show_drive and event.drive else ""
    if event.kind == "detected":
        return (f"  t={t:8.2f} s  k={event.sample:<7d} {who}DETECTED   change near k="
                f"{event.onset_sample} in {', '.join(event.residuals)}")
    if event.kind == "named":
        waits = [_UNDECIDED[u] for u in event.undecided if u in _UNDECIDED]
        line = (f"  t={t:8.2f} s  k={event.sample:<7d} {who}NAMED      {event.target} "
                f"{event.index} ({event.name}): acts as {estimates_text(event.estimates)} now, "
                f"onset k={event.onset_sample}"
                + (f"; undecided: {', '.join(waits)}" if waits else ""))
        if event.candidates:
            alts = "; ".join(f"{c['name']} {estimates_text(c['estimates'])}"
                             for c in event.candidates)
            line += f"\n{'':33}indistinguishable from the bus: {alts}"
        return line
    if event.kind == "accepted":
        line = (f"  t={t:8.2f} s  k={event.sample:<7d} {who}FAULT      {event.target} "
                f"{event.index} ({event.name}): {estimates_text(event.estimates)}, "
                f"onset k={event.onset_sample}")
        if event.candidates:
            alts = "; ".join(f"{c['name']} {estimates_text(c['estimates'])}"
                             for c in event.candidates)
            line += f"\n{'':33}indistinguishable from the bus: {alts}"
        return line
    if event.kind == "refined":
        return (f"  t={t:8.2f} s  k={event.sample:<7d} {who}REFINED    {event.target} "
                f"{event.index} ({event.name}): now {estimates_text(event.estimates)} (the fault "
                f"already known, from k={event.onset_sample} on)")
    if event.kind == "taught":
        noise = ", ".join(f"{n} {v:.4g}" for n, v in event.estimates.items())
        return (f"  t={t:8.2f} s  k={event.sample:<7d} {who}TAUGHT     the drive's noise, "
                f"learned from its first samples: {noise}; monitoring with it")
    if event.kind == "teach_failed":
        reason = event.candidates[0]["reason"] if event.candidates else "?"
        return (f"  t={t:8.2f} s  k={event.sample:<7d} {who}TEACH-IN FAILED: {reason}; "
                "monitoring with the config's noise")
    if event.kind in ("mismatch", "quiet", "matched"):
        ratios = ", ".join(f"{n} {v:.2f}x" for n, v in event.estimates.items())
        what = {
            "mismatch": "MISMATCH   residual noise above its calibrated value (noise or model "
                        "changed; detection widened to it; recalibrate: canfdi calibrate, "
                        "run --teach): ",
            "quiet": "QUIET      residual quieter than configured (detection keeps the "
                     "configured noise; canfdi calibrate would make it more sensitive): ",
            "matched": "MATCHED    residual noise back at its calibrated value: ",
        }[event.kind]
        return f"  t={t:8.2f} s  k={event.sample:<7d} {who}{what}{ratios}"
    return f"  t={t:8.2f} s  k={event.sample:<7d} {who}UNEXPLAINED change detected at k=" \
           f"{event.detected_sample}: no single fault fits"
