"""What the capability model's commands run (``qz capability train``, ``map``; qz_drake.cli.capability):
a trial dataset's training arrays, a training that resumes after an interruption, and the
terrain a command names (a heightmap file or a generator with KEY=VALUE parameters).
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import sys
from pathlib import Path

from qz_drake.capability.dataset import load_training_arrays, merge_training_arrays
from qz_drake.capability.model import UNFINISHED_DIR, save_model, save_network, unfinished_networks
from qz_drake.capability.training import train_networks, training_identity
from qz_drake.config import TerrainConfig, parse_key_values
from qz_drake.errors import bad_value
from qz_drake.scene import load_heightmap_file, make_heightmap
from qz_drake.terrain import HeightMap


def load_dataset(path) -> tuple[dict, dict]:
    """(arrays, manifest) of a trial dataset (qz_drake.capability.dataset), or of several learned
    from together (a list of folders: dataset.merge_training_arrays)."""
    if isinstance(path, (list, tuple)):
        return merge_training_arrays([(p, *load_training_arrays(p)) for p in path])
    return load_training_arrays(path)


def train_resumably(arrays: dict, manifest: dict, config, out, *, restart: bool = False, progress: bool = False):
    """Trains the networks into the model folder ``out`` so that an interruption keeps what
    finished: each network is saved in ``out/unfinished_training/`` as soon as it is trained,
    and the same training run again (same dataset, settings and code) trains only the ones
    missing there; the folder becomes the model (save_model) when all are done. ``restart``
    discards an unfinished training there first. Returns (TrainingResult, networks resumed)."""
    fingerprint, fingerprints = manifest.get("fingerprint"), manifest.get("fingerprints")
    config.check()
    unfinished = Path(out) / UNFINISHED_DIR
    if restart and unfinished.is_dir():
        shutil.rmtree(unfinished)
    identity = training_identity(arrays, fingerprint=fingerprint, fingerprints=fingerprints, config=config)
    finished = unfinished_networks(unfinished, identity) if unfinished.is_dir() else {}
    settings = dataclasses.asdict(config)

    def keep(network):
        save_network(unfinished, network, fingerprint=fingerprint, fingerprints=dict(fingerprints or {}),
                     config=settings, identity=identity)

    try:
        result = train_networks(arrays, fingerprint=fingerprint, fingerprints=fingerprints, config=config,
                                progress=progress, finished=finished, on_network=keep)
    except KeyboardInterrupt:
        done = len(list(unfinished.glob("*.json"))) if unfinished.is_dir() else 0
        print(f"qz capability train: {done} trained networks kept in {unfinished}; the same command trains "
              "the rest", file=sys.stderr)
        raise
    save_model(result, out)
    shutil.rmtree(unfinished, ignore_errors=True)
    return result, sorted(finished)


# What a picture's heights need besides its pixels (HeightMap.from_image), as a scenario's
# terrain.params give them: the cell size and the heights of a black and a white pixel. [m]
PICTURE_SCALE = ("resolution", "min_height", "max_height")


def load_terrain(name_or_file: str, params: list[str] | None, seed: int):
    """A HeightMap from a file (.npz, map-server .yaml, or a picture with its scale given as
    --terrain-param PICTURE_SCALE) or a generator name with KEY=VALUE parameters."""
    path = Path(name_or_file)
    if path.suffix.lower() in HeightMap.IMAGE_SUFFIXES:
        scale = parse_key_values(params, "--terrain-param")
        for key, value in scale.items():
            if key not in PICTURE_SCALE:
                raise bad_value(f"--terrain-param {key}", value,
                                f"a picture takes only {', '.join(PICTURE_SCALE)} (its scale)")
        if "resolution" not in scale or "max_height" not in scale:
            raise bad_value("--terrain", name_or_file,
                            "a picture needs its scale: add --terrain-param resolution=0.05 --terrain-param "
                            "max_height=0.4 (its cell size and the height of a white pixel [m]; a black one is "
                            "min_height, 0 by default), or give a map-server .yaml that names the picture with "
                            "resolution, min_height and max_height")
        if not (math.isfinite(scale["resolution"]) and scale["resolution"] > 0):
            raise bad_value("--terrain-param resolution", scale["resolution"], "must be a positive cell size [m]")
        return load_heightmap_file(path, "--terrain", name_or_file, **scale)
    if path.suffix in (".npz", ".yaml", ".yml"):
        if params:
            raise bad_value("--terrain-param", params, "parameters apply to a generated terrain or a picture, "
                                                       "not a .npz or .yaml heightmap (it carries its own scale)")
        return load_heightmap_file(path, "--terrain", name_or_file)
    return make_heightmap(TerrainConfig(kind=name_or_file, params=parse_key_values(params, "--terrain-param")),
                          seed=seed)


