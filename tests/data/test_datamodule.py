import json
from types import SimpleNamespace

import lightning.pytorch as pl
import numpy as np
import pytest
import torch
from lightning.pytorch.callbacks import ModelCheckpoint

from nerf_transporter import geometry as g
from nerf_transporter.data import episode as ep
from nerf_transporter.data import generate as gen
from nerf_transporter.data.datamodule import RavensDataModule, sample_negative_views
from nerf_transporter.data.preprocess import COLOUR_MEAN, COLOUR_STD
from nerf_transporter.methods import GTStateMLP
from tests.helpers.fake_sim import MARK, PIXEL, changed_world

H, W = g.image_shape(PIXEL)
MARK_VALUE = (MARK / 255.0 - COLOUR_MEAN) / COLOUR_STD


def make(tmp_path, **changes) -> RavensDataModule:
    options = {
        "task": "block-insertion",
        "n_demos": 3,
        "data_dir": str(tmp_path),
        "batch_size": 2,
        "imagery": "oracle",
        "pixel_size": PIXEL,
        "n_negative_views": 3,
        "nerf_views": 2,
        "input_kind": "imagery",
        "samples_per_epoch": 6,
        **changes,
    }
    return RavensDataModule(**options)


def batches(module: RavensDataModule, epoch: int = 0) -> list[dict]:
    loader = module.train_dataloader()
    loader.sampler.set_epoch(epoch)
    return list(loader)


def test_imagery_batches_follow_the_interface_and_labels_follow_content(fake_world, tmp_path):
    module = make(tmp_path)
    module.prepare_data()
    module.setup("fit")
    for batch in batches(module):
        assert (
            batch["pick_image"].shape == (2, 6, H, W) and batch["pick_image"].dtype == torch.float32
        )
        assert batch["place_images"].shape == (2, 4, 6, H, W)
        assert batch["pick_pixel"].shape == (2, 2) and batch["pick_pixel"].dtype == torch.long
        assert batch["place_pixel"].shape == (2, 2) and batch["rotation_bin"].shape == (2,)
        assert ((batch["rotation_bin"] >= 0) & (batch["rotation_bin"] < 36)).all()
        for b in range(2):
            (r, c), (pr, pc) = batch["pick_pixel"][b].tolist(), batch["place_pixel"][b].tolist()
            # augmented images carry the pick mark (red) and the place mark (green) at the labels
            assert torch.isclose(batch["pick_image"][b, 0, r, c], torch.tensor(MARK_VALUE))
            assert torch.isclose(batch["place_images"][b, 0, 1, pr, pc], torch.tensor(MARK_VALUE))


def test_heightmap_and_state_batches(fake_world, tmp_path):
    module = make(tmp_path, input_kind="heightmap")
    module.prepare_data()
    module.setup("fit")
    batch = batches(module)[0]
    assert batch["image"].shape == (2, 6, H, W)
    for key in ("place_z", "place_roll", "place_pitch"):
        assert batch[key].shape == (2,) and batch[key].dtype == torch.float32
    assert (batch["place_roll"].abs() <= np.pi / 6 + 1e-6).all() and (batch["place_z"] > 0).all()
    module = make(tmp_path, input_kind="state")
    module.setup("fit")
    batch = batches(module)[0]
    assert (
        batch["state"].shape == (2, 14)
        and batch["pick"].shape == (2, 7)
        and batch["place"].shape == (2, 7)
    )
    assert module.state_dim == 14  # known without loading a batch


def test_batches_are_deterministic_and_independent_of_workers(fake_world, tmp_path):
    first = make(tmp_path)
    first.prepare_data()
    first.setup("fit")
    parallel = make(tmp_path, num_workers=2)
    parallel.setup("fit")
    a, b = batches(first), batches(parallel)
    for x, y in zip(a, b, strict=True):
        for key in x:
            assert torch.equal(x[key], y[key])
    other_epoch = batches(first, epoch=1)
    assert not torch.equal(a[0]["pick_pixel"], other_epoch[0]["pick_pixel"])
    no_augment = make(tmp_path, augment=False)
    no_augment.setup("fit")
    pixels = torch.cat([batch["pick_pixel"] for batch in batches(no_augment)])
    assert len({tuple(p) for p in pixels.tolist()}) == 3  # one label per demo


@pytest.mark.parametrize("input_kind", ["imagery", "heightmap"])
def test_colour_augmentation_changes_colours_only(fake_world, tmp_path, input_kind):
    plain = make(tmp_path, input_kind=input_kind)
    plain.prepare_data()
    plain.setup("fit")
    recoloured = make(tmp_path, input_kind=input_kind, colour_augment=True)
    recoloured.setup("fit")
    changed = 0
    for x, y in zip(batches(plain), batches(recoloured), strict=True):
        for key in x:
            if key not in ("image", "pick_image", "place_images"):
                assert torch.equal(x[key], y[key])  # labels, views drawn: as without it
                continue
            assert torch.equal(x[key][..., 3:, :, :], y[key][..., 3:, :, :])  # heights as they were
            changed += int(not torch.equal(x[key], y[key]))
    assert changed > 0


def test_missing_data_without_generation_prints_the_command(fake_world, tmp_path):
    module = make(tmp_path, generate_missing=False)
    module.prepare_data()  # does nothing
    with pytest.raises(FileNotFoundError) as error:
        module.setup("fit")
    command = (
        "nerf-transporter generate --task block-insertion --setting normal --split train --episodes 3 "
        f"--imagery oracle --data-dir {tmp_path} --pixel-size 0.0125 --nerf-views 2"
    )
    assert command in str(error.value)
    assert gen.main(command.split()[2:] + ["--no-progress"]) == 0
    module.setup("fit")
    assert len(module.train_dataset) == 3


def test_input_kind_from_the_trained_module_and_validation_split(fake_world, tmp_path):
    module = make(tmp_path, input_kind=None, n_val_demos=1)
    state_module = SimpleNamespace(input_kind="state")
    module.trainer = SimpleNamespace(
        lightning_module=state_module, state=SimpleNamespace(fn="test")
    )
    module.prepare_data()  # `lightning test` runs test seeds: nothing to generate
    assert not list(tmp_path.iterdir())
    module.trainer = SimpleNamespace(lightning_module=state_module, state=SimpleNamespace(fn="fit"))
    module.prepare_data()
    module.setup("fit")
    assert module.train_dataset.input_kind == "state"
    assert [d.seed for d in module.val_dataset.demos] == [1_000_000]
    assert [d.seed for d in module.train_dataset.demos] == [0, 4, 6]
    assert len(list(module.val_dataloader())) == 1
    with pytest.raises(ValueError, match="input_kind"):
        make(tmp_path, input_kind=None).setup("fit")


def test_non_imagery_methods_do_not_generate_nerf_imagery(fake_world, tmp_path):
    module = make(tmp_path, imagery="nerf", input_kind="heightmap")
    module.prepare_data()
    assert [p.name for p in tmp_path.iterdir()] == ["block-insertion-normal-train-oracle-px0.0125"]
    module.setup("fit")
    assert len(module.train_dataset) == 3


def test_negative_views_are_distinct_and_near_ones_weighted_up():
    views = g.view_grid("normal")
    positive = g.top_down_view_index(views)
    neighbour = np.linalg.norm(views - views[positive], axis=1) < 0.26  # 8 neighbours + itself

    def neighbour_share(scale):
        rng = np.random.default_rng(0)
        draws = [sample_negative_views(rng, views, positive, 4, scale) for _ in range(300)]
        for negatives in draws:
            assert len(set(negatives.tolist())) == 4 and positive not in negatives
        return neighbour[np.concatenate(draws)].mean()

    assert neighbour_share(None) == pytest.approx(8 / 48, abs=0.04)
    assert neighbour_share(0.1) > 0.6


def test_negative_view_scale_must_be_positive(tmp_path):
    with pytest.raises(ValueError, match="negative_view_scale"):
        make(tmp_path, negative_view_scale=0.0)


def test_data_of_another_world_is_not_trained_on(fake_world, tmp_path, monkeypatch):
    make(tmp_path).prepare_data()
    other_world = changed_world(gen.fingerprint.world())
    monkeypatch.setattr(gen.fingerprint, "world", lambda: other_world)
    module = make(tmp_path, generate_missing=False)
    with pytest.raises(ep.WorldMismatchError) as error:
        module.setup("fit")
    assert "the physics and tasks (physics) changed" in str(error.value)
    assert str(error.value).endswith(
        "nerf-transporter generate --task block-insertion --setting normal --split train "
        f"--episodes 3 --imagery oracle --data-dir {tmp_path} --pixel-size 0.0125 --nerf-views 2 "
        "--regenerate"
    )
    with pytest.raises(ep.WorldMismatchError):
        make(tmp_path).prepare_data()  # generation refuses too, and deletes nothing
    assert len(ep.list_episodes(tmp_path / "block-insertion-normal-train-oracle-px0.0125")) == 3


def test_edited_label_is_not_trained_on(fake_world, tmp_path):
    module = make(tmp_path)
    module.prepare_data()
    path = ep.list_episodes(tmp_path / "block-insertion-normal-train-oracle-px0.0125")[1].path
    meta = json.loads((path / "meta.json").read_text())
    meta["action"]["place"]["quat_xyzw"] = [0.0, 0.0, 0.0, 1.0]
    (path / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ep.CorruptEpisodeError, match=rf"{path.name}: meta\.json does not match"):
        module.setup("fit")


def test_a_fit_resumed_mid_epoch_trains_as_the_uninterrupted_fit(fake_world, tmp_path):
    """3 batches an epoch; the checkpoint at step 4 lies inside epoch 1: resumed from it, the fit
    must see the rest of epoch 1's samples, not that epoch from its start again."""
    make(tmp_path, input_kind="state").prepare_data()

    def fit(max_steps: int, ckpt_path=None, checkpoints=None) -> GTStateMLP:
        pl.seed_everything(0)
        model = GTStateMLP(state_dim=14)
        callbacks = [ModelCheckpoint(checkpoints, every_n_train_steps=2, save_top_k=-1)]
        trainer = pl.Trainer(
            max_steps=max_steps,
            logger=False,
            enable_progress_bar=False,
            enable_model_summary=False,
            callbacks=callbacks if checkpoints else [],
            enable_checkpointing=bool(checkpoints),
        )
        trainer.fit(model, datamodule=make(tmp_path, input_kind="state"), ckpt_path=ckpt_path)
        return model

    straight = fit(6, checkpoints=tmp_path / "checkpoints")
    (mid_epoch,) = (tmp_path / "checkpoints").glob("*step=4.ckpt")
    resumed = fit(6, ckpt_path=mid_epoch)
    for name, value in straight.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[name], value, msg=name)


@pytest.mark.parametrize(
    ("recorded", "changes"),
    [
        # written before checkpoints named their imagery: trained on the reference imagery
        ({}, {}),
        ({"iterations": 800}, {"iterations": 800}),
        # written since: the default imagery's changes, named
        (None, {"colour_init": "table", "sparsity_weight": 0.0003}),
    ],
)
def test_a_checkpoint_is_read_back_on_the_imagery_it_was_trained_on(tmp_path, recorded, changes):
    """Whatever this code's imagery defaults: a policy tested on imagery other than its training's
    fails where it would succeed (a hanging-disks checkpoint: 16 -> 2 of 100, docs/imagery.md)."""
    datamodule = RavensDataModule(
        task="hanging-disks", data_dir=str(tmp_path), generate_missing=False
    )
    hparams = dict(datamodule.hparams)
    if recorded is not None:
        hparams["imagery_config"] = recorded
    checkpoint = {"pytorch-lightning_version": pl.__version__}
    torch.save(checkpoint | {"datamodule_hyper_parameters": hparams}, tmp_path / "a.ckpt")
    restored = RavensDataModule.load_from_checkpoint(tmp_path / "a.ckpt", weights_only=True)
    scene = restored.generation_config("test").scene
    assert scene.imagery_changes() == changes
    # and saved again, it names the same imagery
    torch.save(checkpoint | {"datamodule_hyper_parameters": dict(restored.hparams)}, tmp_path / "b")
    again = RavensDataModule.load_from_checkpoint(tmp_path / "b", weights_only=True)
    assert again.generation_config("test").scene.imagery_changes() == changes
