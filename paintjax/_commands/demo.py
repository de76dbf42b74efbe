"""`paintjax demo` (the job `make demo` runs): five-angle comparison of both reference samples."""

from __future__ import annotations

from . import microfacet


def register(sub) -> None:
    p = sub.add_parser("demo", help="the main job: five-angle L* of Silver #1 and #2 against measurement")
    p.set_defaults(func=run)


def run(args) -> int:
    for name in ("silver1", "silver2"):
        microfacet.run(type("Args", (), dict(sample=name, shape=None, scale=None, reflectance=None, n=None, no_exit_occlusion=False, json=False)))
        print()
    return 0
