"""Small weights-only policies shipped with the package (`nerf-transporter try`), one file per task
and method; `manifest.json` holds their provenance."""

from pathlib import Path

PRETRAINED_DIR = Path(__file__).resolve().parent
