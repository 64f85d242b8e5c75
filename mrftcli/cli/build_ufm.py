"""``mrft-ident build-ufm``: build unit frequency / unit gain manifolds for given betas."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import InputError
from .options import BETA, quiet_option, tqdm_progress


@click.command("build-ufm")
@click.option("--beta", "betas", type=BETA, multiple=True, help="A beta in (-1, 1); repeat for several.")
@click.option("--shipped", is_flag=True, help="Build the shipped set: beta -0.9 to -0.1 in steps of 0.05.")
@click.option("--out", "-o", "out", type=click.Path(file_okay=False), required=True,
              help="Folder the manifolds are written to (created if missing).")
@click.option("--n-tp", type=click.IntRange(8, 4001), default=None, help="Grid points over Tp*Omega (default 201).")
@click.option("--n-td", type=click.IntRange(8, 4001), default=None, help="Grid points over Td*Omega (default 201).")
@quiet_option()
def build_ufm(betas: tuple[float, ...], shipped: bool, out: str, n_tp: int | None, n_td: int | None,
              quiet: bool) -> None:
    """Build UFM/UGM files (ufm_beta±B.npz + .json) for the given betas into OUT.

    Grids are log-spaced: Tp*Omega in [1e-3, 1e2], Td*Omega in [1e-2, 1e3] (Omega = 1 rad/s).
    Example: mrft-ident build-ufm --beta -0.4 --beta -0.7 --out my_manifolds
    """
    import numpy as np

    from ..mrft.ufm import DEFAULT_TD, DEFAULT_TP, SHIPPED_BETAS, build_manifolds, save_manifold

    chosen = list(betas) + (list(SHIPPED_BETAS) if shipped else [])
    if not chosen:
        raise InputError("give at least one --beta (or --shipped)")
    chosen = sorted(set(round(b, 6) for b in chosen))
    tp = DEFAULT_TP if n_tp is None else np.geomspace(DEFAULT_TP[0], DEFAULT_TP[-1], n_tp)
    td = DEFAULT_TD if n_td is None else np.geomspace(DEFAULT_TD[0], DEFAULT_TD[-1], n_td)
    with tqdm_progress("UFM", unit="beta", enabled=not quiet) as progress:
        manifolds = build_manifolds(chosen, tp, td, progress=progress)
    paths = [save_manifold(m, Path(out)) for m in manifolds]
    click.echo(f"wrote {len(paths)} manifold(s) to {out}: " + ", ".join(p.name for p in paths))
