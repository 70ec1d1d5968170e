"""``merlin dialect install|uninstall|show [--pymavlink-dir DIR]``: the Merlin MAVLink dialect in pymavlink's
own tools.

After ``merlin dialect install``, ``mavlogdump.py --dialect merlin flight.tlog``, ``MAVLINK_DIALECT=merlin
MAVExplorer.py flight.tlog`` and ``mavproxy.py --dialect=merlin`` decode every ``MERLIN_*`` message of a Merlin tlog
(``merlin.link.dialect_install``: the XML and the generated modules beside pymavlink's shipped dialects).
``--pymavlink-dir`` names another pymavlink package directory (default: the one this Python imports).
Exit codes: 0 done, 2 the directory is not a pymavlink package.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser("dialect", help="install the Merlin MAVLink dialect into pymavlink's tools",
                       description=__doc__.split("\n\n")[1] if __doc__ else None)
    p.add_argument("action", choices=("install", "uninstall", "show"),
                   help="install: make mavlogdump/MAVExplorer/MAVProxy decode MERLIN_*; uninstall: remove it; "
                        "show: where the dialect XML is and whether it is installed")
    p.add_argument("--pymavlink-dir", type=Path, default=None,
                   help="the pymavlink package directory to install into (default: the one Python imports)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from merlin.config.loader import ConfigError
    from merlin.link.dialect import dialect_xml_path, icd_version_string
    from merlin.link.dialect_install import install, installed_files, pymavlink_dir, uninstall

    target = args.pymavlink_dir or pymavlink_dir()
    if args.action == "show":
        print(f"dialect XML: {dialect_xml_path()} (ICD {icd_version_string()})")
        for f in installed_files(target):
            print(f"  {'installed' if f.exists() else 'absent   '}  {f}")
        return 0
    if args.action == "uninstall":
        for f in uninstall(target):
            print(f"removed {f}")
        return 0
    try:
        files = install(target)
    except FileNotFoundError as exc:
        raise ConfigError(str(target), [f"--pymavlink-dir: {exc}"]) from None
    for f in files:
        print(f"wrote {f}")
    print("now: mavlogdump.py --dialect merlin FLIGHT.tlog; MAVLINK_DIALECT=merlin MAVExplorer.py FLIGHT.tlog; "
          "mavproxy.py --dialect=merlin")
    return 0
