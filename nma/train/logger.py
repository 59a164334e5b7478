"""Experiment loggers: wandb (offline by default, no network needed) or none."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the settings' type, for the reader
    from ..schema import LoggerConfig


class NoLogger:
    def log(self, record: dict, step: int) -> None:
        pass

    def finish(self) -> None:
        pass


class WandbLogger:
    def __init__(self, run_dir: Path, project: str, mode: str, config: dict, name: str):
        import wandb

        os.environ.setdefault("WANDB_SILENT", "true")
        self.run = wandb.init(
            project=project,
            dir=str(run_dir),
            mode=mode,
            config=config,
            name=name,
            reinit="finish_previous",
        )

    def log(self, record: dict, step: int) -> None:
        self.run.log({k: v for k, v in record.items() if isinstance(v, (int, float))}, step=step)

    def finish(self) -> None:
        self.run.finish()


def make_logger(cfg: LoggerConfig, run_dir: Path, config: dict, name: str, is_root: bool):
    if cfg.name == "none" or not is_root:
        return NoLogger()
    return WandbLogger(run_dir, cfg.project, cfg.mode, config, name)
