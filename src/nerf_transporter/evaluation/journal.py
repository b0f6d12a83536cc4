"""An evaluation's finished episodes, journalled as each ends, so that an interrupted evaluation
resumes where it stopped (a 100-episode test on NeRF imagery is most of an hour of a core).

An episode is a function of its seed, so an episode journalled by an earlier process stands for the
one this process would run, provided everything else it depends on is the same: the checkpoint's
bytes, the split, the scene (task, setting, imagery, and the imagery key, which carries the world
fingerprint), the policy's test-time options and the code (its commit, and the diff of a dirty
tree). That is the journal's `identity`; its file is named by the identity's hash, so a journal is
only ever read by an evaluation of the same identity, and one of another identity (another commit,
another view choice) starts its own. The first line of the file is the identity, for a reader;
each further line one episode's `EpisodeResult.to_json()`.

Episodes that erred (not the robot's doing) are not journalled: a resumed evaluation runs them
again. A line cut short by an interruption is dropped when the journal is read. The caller removes
the journal once the evaluation's record is written, so that evaluating again runs every episode
again.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

from nerf_transporter.atomic import write_text
from nerf_transporter.evaluation.cache import config_hash
from nerf_transporter.evaluation.rollout import EpisodeResult

log = logging.getLogger(__name__)


class EpisodeJournal:
    """The finished episodes of one evaluation (`identity`), in `folder`/<identity hash>.jsonl."""

    def __init__(self, folder: str | os.PathLike, identity: dict[str, Any]) -> None:
        self.identity = identity
        self.path = Path(folder) / f"{config_hash(identity)}.jsonl"

    def finished(self, seeds: list[int]) -> dict[int, EpisodeResult]:
        """The journalled episodes among `seeds`, by seed ({} without a journal)."""
        if not self.path.exists():
            return {}
        lines = self.path.read_text().splitlines()
        results: dict[int, EpisodeResult] = {}
        for number, line in enumerate(lines[1:], start=2):
            try:
                result = EpisodeResult.from_json(json.loads(line))
            except (ValueError, TypeError) as error:
                if number < len(lines):  # only the last line can be cut short by an interruption
                    raise ValueError(
                        f"the episode journal {self.path} is damaged at line {number} ({error}); "
                        "delete it to run the evaluation's episodes again"
                    ) from error
                log.warning(
                    "dropping the last, unfinished line of the episode journal %s", self.path
                )
                write_text(self.path, "".join(f"{kept}\n" for kept in lines[:-1]))
                break
            results[result.seed] = result
        return {seed: results[seed] for seed in seeds if seed in results}

    def record(self, result: EpisodeResult) -> None:
        """Append a finished episode (one that erred is left out), on disk before returning."""
        if result.error is not None:
            return
        if not self.path.exists():
            write_text(self.path, json.dumps({"journal": self.identity}) + "\n")
        with open(self.path, "a") as file:
            file.write(json.dumps(result.to_json()) + "\n")
            file.flush()
            os.fsync(file.fileno())

    def remove(self) -> None:
        """Forget the journal (its evaluation's record is written)."""
        self.path.unlink(missing_ok=True)
