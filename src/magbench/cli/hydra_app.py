"""Hydra's own entry point, for multirun and launcher plugins (SLURM via submitit, etc.).

``python -m magbench`` composes the configuration itself so that bad values give one line and
exit status 2. Hydra's launchers need ``@hydra.main``; this module provides it with the same
configuration and the same run function::

    python -m magbench.cli.hydra_app -m sweep=gamma,beta,K,sigma            # one job per sweep
    python -m magbench.cli.hydra_app -m hydra/launcher=submitit_slurm \\
        sweep=gamma,beta,K,sigma n_jobs=32 +hydra.launcher.cpus_per_task=32

Each job writes ``<results_dir>/<sweep>/`` as a plain run would (Hydra's own log folders go to
``outputs/`` and ``multirun/``, which git ignores).
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

from magbench.cli.commands import run
from magbench.cli.config import UsageError, config_dir


@hydra.main(version_base="1.3", config_path=str(config_dir()), config_name="config")
def app(cfg: DictConfig) -> None:
    """Run the sweep of one (multirun) job."""
    try:
        run(cfg)
    except UsageError as exc:
        print(f"magbench: error: {exc}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    app()
