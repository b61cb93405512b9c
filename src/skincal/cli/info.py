"""``skincal info``: summary of a dataset file (placeholder until the dataset reader lands)."""

from __future__ import annotations

from pathlib import Path

import typer

from skincal.cli.app import app, console


@app.command()
def version() -> None:
    """Print the skincal version."""
    import skincal

    console.print(skincal.__version__)


@app.command()
def info(path: Path = typer.Argument(..., help="dataset file (.h5)")) -> None:
    """Summarise a dataset: robot, units, duration, segments, sample rates."""
    from skincal.data.hdf5 import read_dataset  # noqa: F401  (lands with the dataset reader)

    raise NotImplementedError
