"""Bounds on what the tool accepts, in one place. Past each, a one-line
``ParameterError`` names the parameter and its allowed range before any work
is done (docs/caches.md and docs/cli.md say where each applies)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Limits", "LIMITS"]


@dataclass(frozen=True)
class Limits:
    """The bounds (see the module docstring)."""

    #: Nesting of arrays and objects in any JSON file read (the tool's own files
    #: nest at most 8 deep; Python's parser would recurse out past about 1000).
    json_depth: int = 64
    #: Size of a JSON or CSV file read, bytes (the full v5 board's runs file is
    #: 47 MB compressed, 260 MB of JSON; parsing may take 26 times the file in memory).
    json_bytes: int = 512 * 1024 ** 2
    #: Nesting of list files naming list files (``stepdamp motors``).
    list_file_depth: int = 8
    #: Characters of a motor's name (printable).
    name_chars: int = 200
    #: Motors in a ``--motors`` file.
    custom_motors: int = 1000
    #: Memory of one trace, bytes (or a quarter of the machine's, if less).
    trace_bytes: int = 2 * 1024 ** 3
    #: RK4 plant steps of one simulated run (PWM periods x substeps): about
    #: half an hour of a core; 1e4 s at 20 kHz and one substep is 2e8.
    plant_steps: int = 10 ** 10


LIMITS = Limits()
