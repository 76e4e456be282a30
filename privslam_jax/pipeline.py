"""The privacy-preserving edge-assisted SLAM pipeline, composed from the stages.

Stages (DESIGN §1), each a plain function of the previous stage's output:

1. **data**: render the synthetic street world into a KITTI-layout sequence
   (:func:`privslam_jax.commands.synth.write_kitti_sequence`).

The stages that follow (privacy filter, SLAM on original and filtered frames, line lifting and
attacks) join this function as they land; each writes its outputs under the run folder and adds
its numbers to the report.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

__all__ = ["PipelineConfig", "run_pipeline"]


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """Settings of :func:`run_pipeline` (the embedded default is the default instance)."""

    frames: int = 60
    """Number of synthetic frames."""
    seed: int = 0
    """Synthetic world seed."""
    width: int = 640
    """Image width, px."""
    height: int = 192
    """Image height, px."""
    name: str = "synth"
    """Sequence name in the KITTI layout."""


def run_pipeline(config: PipelineConfig, out: str | Path, progress: bool = True) -> dict[str, Any]:
    """Run every available stage on the synthetic default; returns a JSON-able report with ``summary``."""
    from privslam_jax.commands.synth import sequence_stats, summarize_sequence, write_kitti_sequence
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    if config.frames < 1:
        raise ValueError(f"frames must be at least 1, got {config.frames}")
    out = Path(out)
    seq = make_sequence(
        SynthConfig(width=config.width, height=config.height, num_frames=config.frames, seed=config.seed, stereo=True)
    )
    records: list[Any] = []
    seq_dir = write_kitti_sequence(seq, out, config.name, progress=progress, collect=records)
    return {
        "sequence": str(seq_dir),
        "data": sequence_stats(seq, frames=records),
        "summary": summarize_sequence(seq, frames=records, title=f"synthetic sequence {seq_dir}"),
    }
