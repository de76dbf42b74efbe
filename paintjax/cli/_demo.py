"""`paintjax demo` (the job `make demo` runs): the five-angle comparison of both reference samples.

It is `paintjax table1` with its defaults: measured L* next to the hybrid ray-wave model, mirror
platelets through the same tracer and the analytic single-scatter model.
"""

from __future__ import annotations

from . import _table1 as table1


def register(sub) -> None:
    p = sub.add_parser("demo", help="the main job (same as table1): five-angle L* of Silver #1 and #2 vs measurement")
    table1.add_arguments(p)
