"""What ``stepdamp export`` writes for each entry of a board: the board's
``firmware`` field (:func:`firmware_field`; left out of the fingerprint, a
property of the code, not a result) and LEADERBOARD.md's section on it
(:func:`render_firmware`)."""

from __future__ import annotations

from typing import Any, Mapping

from .registry import PolicySource

__all__ = ["firmware_field", "render_firmware"]


def firmware_field(sources: Mapping[str, PolicySource]) -> dict[str, dict[str, Any]]:
    """Per entry, what ``stepdamp export`` writes (:func:`.firmware.export_kind`:
    "law", "online table" or "network") and for which modes
    (:func:`.firmware.export_modes`); an entry it cannot export has no modes. An
    entry that names the drives it exports for (``firmware_drives``, e.g. a
    network trained on the voltage-mode drive only) has them as ``drives``."""
    from .firmware import export_kind, export_modes

    out = {}
    for src in sources.values():
        try:
            policy = src.make()
            modes = export_modes(policy)
            kind = export_kind(policy) if modes else ""
        except Exception:       # a description, never worth a board's runs
            kind, modes = "", ()
        out[src.name] = {"kind": kind, "modes": list(modes)}
        drives = getattr(policy, "firmware_drives", None) if modes else None
        if drives is not None:
            out[src.name]["drives"] = list(drives)
    return out


def render_firmware(board: Mapping[str, Any]) -> list[str]:
    """LEADERBOARD.md's section on what ``stepdamp export`` writes for each entry
    (the board's ``firmware``: kind and modes per entry); none for a board
    without it."""
    groups: dict[tuple[str, tuple[str, ...], tuple[str, ...]], list[str]] = {}
    for name, f in (board.get("firmware") or {}).items():
        # Only a drive other than the current-mode one every other entry runs on is said.
        drives = tuple(f.get("drives") or ())
        special = drives if len(drives) == 1 and drives[0] != "current" else ()
        groups.setdefault((f["kind"], tuple(f["modes"]), special), []).append(name)
    if not groups:
        return []
    label = {"law": "a fixed law", "network": "the policy network",
             "online table": "an online table (it adapts while it runs: its update and "
                             "state)"}
    lines = ["## Firmware export", "",
             "What `stepdamp export ENTRY --motor M` writes for each entry, as C99 and "
             "JSON (docs/firmware.md):", ""]
    for (kind, modes, drive), names in sorted(groups.items(),
                                              key=lambda g: (not g[0][1], g[0])):
        what = (f"{label.get(kind, kind)}, " + ("in open loop and servo" if len(modes) > 1
                                                 else f"in {modes[0].replace('-', ' ')} only")
                + (f", on the {drive[0]}-mode drive only" if drive else "")
                if modes else "nothing (docs/firmware.md says why for each)")
        lines.append(f"- {what}: " + ", ".join(f"`{n}`" for n in sorted(names)))
    return lines
