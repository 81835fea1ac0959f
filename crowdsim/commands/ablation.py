"""``crowdsim ablation``: paper 1's Table 3, the BQP tracker's terms switched on one by one.

``crowdsim ablation --suite NAME|DIR | --sequences DIR [--only SEQ ...] [--set NAME=VALUE ...]
[--frames N] [--workers N] [--backend local|ray [--address ADDR]] --out DIR``

Rows: B, B+Mo, B+Mo+SP, B+Mo+Gr, B+Mo+Gr+NMo and the full objective, each with NCC and with
KCF appearance (:mod:`tracker.bqp.ablation`); the paper's Table 3 figures (``ablation@15`` of
the suite's ``paper.json``) beside ours. ``--suite``, ``--sequences`` (your own MOT
sequences: no papers' figures), resuming and the checked cells as in ``crowdsim compare``;
``--set`` gives every row a BQP parameter the rows do not set themselves
(``--set fw_variant=block``).
"""

from __future__ import annotations

import argparse

from crowdsim.commands._table_args import (
    add_set_argument,
    add_table_arguments,
    run_table_command,
    table_source,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ablation",
        help="BQP term ablation on a suite (paper 1, Table 3)",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    add_table_arguments(p, sequences=True)
    add_set_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from crowdsim.lab.experiments import ablation_rows

    return run_table_command(
        args, ablation_rows(), f"ablation on {table_source(args)}", "ablation@15"
    )
