"""``ifmi methods``: the estimation methods ``--method`` accepts, with a one-line summary each."""

from __future__ import annotations

from ifmi.tracking.methods import ENTRY_POINT_GROUP, available_methods, warn_shadowing_plugins

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "methods",
        help="list the estimation methods (built in and installed plugins)",
        description="List every method name that --method accepts: the built-in front ends and "
                    f"those installed packages register under the entry-point group "
                    f"'{ENTRY_POINT_GROUP}'. Any factory can also be named as "
                    "package.module:factory.",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    methods = available_methods(with_summary=True)
    width = max(len(m.name) for m in methods)
    for m in methods:
        origin = "" if m.source == "built-in" else f" [{m.source}]"
        print(f"{m.name:<{width}}  {m.summary}{origin}")
    print("(or any factory as package.module:factory)")
    warn_shadowing_plugins()
    return 0
