"""``gaitrig markers``: printable marker sheet (PDF at true size, or PNG pages).

Example: ``gaitrig markers --ids 1-8 --size 0.20 -o markers.pdf``. Errors: one line on
stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import sys

HELP = "printable calibration marker sheet (PDF/PNG at true size)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's options."""
    parser.add_argument("--ids", default="1-8",
                        help="marker ids: ranges and lists, e.g. 1-8 or 1,2,5-7 (default 1-8)")
    parser.add_argument("--size", type=float, default=0.20,
                        help="printed edge length of the black square in metres (default 0.20)")
    parser.add_argument("-o", "--output", default="markers.pdf",
                        help="output .pdf (multi-page) or .png (one file per page)")
    parser.add_argument("--dict", dest="dictionary", default="DICT_4X4_50",
                        help="marker dictionary, e.g. DICT_4X4_50 (default), APRILTAG_36h11")
    parser.add_argument("--paper", default="a4", choices=["a4", "letter", "a3"],
                        help="paper size (default a4)")


def run(args: argparse.Namespace) -> int:
    """Write the sheet and print the written files."""
    from engine.calibration.markers import write_marker_sheet
    from engine.errors import GaitrigError

    try:
        files = write_marker_sheet(args.ids, args.size, args.output,
                                   dictionary=args.dictionary, paper=args.paper)
    except GaitrigError as exc:
        print(f"gaitrig markers: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"gaitrig markers: cannot write {args.output}: {exc.strerror}", file=sys.stderr)
        return 2
    for f in files:
        print(f)
    return 0
