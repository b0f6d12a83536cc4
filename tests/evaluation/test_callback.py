"""Closed loop inside Lightning: SuccessRateCallback during fit, and `trainer.test` on a checkpoint."""

import json
import math
from pathlib import Path

import lightning.pytorch as pl
import numpy as np
import pytest
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.loggers import TensorBoardLogger
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.plugins.hparams import plugin_data_pb2
from torch.utils.data import DataLoader

from nerf_transporter.data.generate import GenerationConfig
from nerf_transporter.data.seeds import seed_loader
from nerf_transporter.evaluation import callback as callback_module
from nerf_transporter.evaluation import rollout as rollout_module
from nerf_transporter.evaluation.callback import SuccessRateCallback
from nerf_transporter.evaluation.metrics import wilson_interval
from nerf_transporter.evaluation.rollout import EpisodeResult
from nerf_transporter.evaluation.testing import ClosedLoopTestCallback
from nerf_transporter.experiments.report import main as report_main

UPRIGHT = np.array([0.0, 0.0, 0.0, 1.0])


class TinyStateMethod(pl.LightningModule):
    """A one-parameter state policy: places wherever its bias says."""

    name = "tiny"
    input_kind = "state"

    def __init__(self):
        super().__init__()
        self.bias = torch.nn.Parameter(torch.zeros(3))
        self.act_calls = []

    def training_step(self, batch, batch_idx):
        return (self.bias - 0.1).pow(2).sum() + 0 * batch.sum()

    def test_step(self, batch, batch_idx):
        """Nothing: the test seeds are played by ClosedLoopTestCallback."""

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)

    def act(self, observation):
        self.act_calls.append((self.global_step, self.training, observation["state"].shape))
        place = np.array([0.5, 0.1, 0.05]) + self.bias.detach().numpy()
        return {"pick": (np.array([0.5, 0.0, 0.02]), UPRIGHT), "place": (place, UPRIGHT)}


class TinyData(pl.LightningDataModule):
    """Stands in for RavensDataModule: its generation config, a few batches and two test seeds
    (run in this process unless `test_workers` says otherwise)."""

    setting = "normal"
    test_setting = "challenging"

    def __init__(self, test_workers=1):
        super().__init__()
        self.test_workers = test_workers

    def generation_config(self, split, imagery=None):
        return GenerationConfig("block-insertion", "normal", split, imagery or "oracle")

    def train_dataloader(self):
        return DataLoader(torch.zeros(8, 1), batch_size=2)

    def test_dataloader(self):
        return seed_loader("test", 2)


@pytest.fixture
def fitted(tmp_path):
    callback = SuccessRateCallback(
        every_n_steps=2,
        episodes=2,
        cache_dir=str(tmp_path / "cache"),
        strip_episodes=1,
        eval_workers=1,  # in this process, where act_calls are recorded
    )
    checkpoint = ModelCheckpoint(
        dirpath=tmp_path / "checkpoints",
        monitor="eval/success_rate",
        mode="max",
        every_n_train_steps=2,
        filename="step{step}-success{eval/success_rate:.2f}",
        auto_insert_metric_name=False,
    )
    trainer = pl.Trainer(
        max_steps=2,
        logger=TensorBoardLogger(tmp_path, name="logs", default_hp_metric=False),  # as the CLI's
        callbacks=[callback, checkpoint],
        enable_progress_bar=False,
        enable_model_summary=False,
        accelerator="cpu",
    )
    model = TinyStateMethod()
    trainer.fit(model, datamodule=TinyData())
    return trainer, model, checkpoint


def test_callback_evaluates_two_episodes_and_logs_rate_interval_and_count(fitted):
    trainer, model, checkpoint = fitted
    # two validation episodes at step 2, in eval mode; the end of fit does not repeat them
    assert [(step, training) for step, training, _ in model.act_calls] == [(2, False), (2, False)]
    metrics = trainer.callback_metrics
    assert metrics["eval/episodes"].item() == 2
    rate = metrics["eval/success_rate"].item()
    # the tiny policy places at one fixed point, where neither seed's fixture lies: both fail
    # (a mixed round's rate: test_validation_logs_the_rate_and_interval_of_a_mixed_round)
    assert rate == 0.0
    low, high = wilson_interval(0, 2)
    assert metrics["eval/success_rate_low"].item() == pytest.approx(low)
    assert metrics["eval/success_rate_high"].item() == pytest.approx(high)

    events = EventAccumulator(trainer.logger.log_dir, size_guidance={"images": 0}).Reload()
    logged = {name: events.Scalars(name) for name in events.Tags()["scalars"]}
    assert [(e.step, e.value) for e in logged["eval/episodes"]] == [(2, 2.0)]
    assert logged["eval/success_rate"][0].value == pytest.approx(rate)
    strip = events.Images("eval/rollouts")
    # one captioned column: the before and after views (2 x 320 rows), a caption band, a frame
    assert len(strip) == 1 and strip[0].height > 2 * 320 + 8 and strip[0].width == 160 + 8
    # the first validation episode as a video in the run folder and an animated GIF in TensorBoard
    (video,) = Path(trainer.log_dir, "videos", "step000002").glob("*.mp4")
    assert video.name == "block-insertion-normal-seed1000000-tiny.mp4"
    (gif,) = events.Images("eval/rollout_video")
    assert gif.step == 2 and gif.encoded_image_string.startswith(b"GIF8")

    # ModelCheckpoint monitored the validation success rate
    assert checkpoint.best_model_score.item() == pytest.approx(rate)
    assert checkpoint.best_model_path.endswith(f"step2-success{rate:.2f}.ckpt")


def test_hparams_tab_compares_methods_by_validation_success(fitted):
    trainer, model, checkpoint = fitted
    events = EventAccumulator(trainer.logger.log_dir).Reload()
    content = events.PluginTagToContent("hparams")
    data = [plugin_data_pb2.HParamsPluginData.FromString(raw) for raw in content.values()]
    experiment = next(d.experiment for d in data if d.HasField("experiment"))
    session = next(d.session_start_info for d in data if d.HasField("session_start_info"))
    assert [info.name.tag for info in experiment.metric_infos] == ["eval/success_rate"]
    assert session.hparams["method"].string_value == "tiny"
    assert session.hparams["task"].string_value == "block-insertion"
    assert session.hparams["max_steps"].number_value == 2
    assert "hp_metric" not in events.Tags()["scalars"]


def test_lightning_test_writes_results_beside_the_checkpoint(fitted, tmp_path, capsys):
    trainer, model, checkpoint = fitted
    ckpt = checkpoint.best_model_path
    test_callback = ClosedLoopTestCallback()
    tester = pl.Trainer(
        logger=False, enable_progress_bar=False, accelerator="cpu", callbacks=[test_callback]
    )
    # the two test episodes run in two worker processes
    metrics = tester.test(model, datamodule=TinyData(test_workers=2), ckpt_path=ckpt)[0]
    # one file per checkpoint; tested in another setting than trained in: the name says which
    results = json.loads(
        (Path(ckpt).parent / f"results-{Path(ckpt).stem}-challenging.json").read_text()
    )
    assert results["method"] == "tiny" and results["split"] == "test"
    assert results["imagery"] is None  # a state method builds no imagery
    assert (results["task"], results["setting"]) == ("block-insertion", "challenging")
    assert results["checkpoint"] == ckpt and results["global_step"] == 2
    assert [episode["seed"] for episode in results["episode_results"]] == [1, 3]
    successes = sum(episode["success"] for episode in results["episode_results"])
    failures = [e["failure"] for e in results["episode_results"] if not e["success"]]
    assert results["episodes"] == 2 and results["successes"] == successes
    assert sum(results["failures"].values()) == len(failures) and all(failures)
    assert results["errors"] == 0 and results["erred_seeds"] == []
    assert len(results["world"]) == 16  # the world fingerprint the episodes were played in
    assert (results["ci_low"], results["ci_high"]) == pytest.approx(wilson_interval(successes, 2))
    assert metrics["test/episodes"] == 2
    assert metrics["test/success_rate"] == pytest.approx(successes / 2)
    assert test_callback.record == results  # what the CLI reads for its exit status
    low, high = round(100 * results["ci_low"]), round(100 * results["ci_high"])
    rate = f"{round(100 * successes / 2)}% (2, {low}-{high}) - {successes} of 2"
    assert f"test success: {rate}\n" in capsys.readouterr().out

    # a method this package does not have is no row of the table: report names the record
    assert report_main([str(tmp_path)]) == 2
    assert 'method "tiny" is none of this package\'s' in capsys.readouterr().err


def test_no_results_file_is_replaced(fitted, tmp_path):
    trainer, model, checkpoint = fitted
    first = Path(checkpoint.best_model_path)
    second = first.with_name("step4-success0.00.ckpt")
    second.write_bytes(first.read_bytes())
    for ckpt in (first, second, first):
        tester = pl.Trainer(
            logger=False,
            enable_progress_bar=False,
            accelerator="cpu",
            callbacks=[ClosedLoopTestCallback()],
        )
        tester.test(model, datamodule=TinyData(), ckpt_path=str(ckpt))
    names = sorted(path.name for path in first.parent.glob("results*.json"))
    assert names == [
        f"results-{first.stem}-challenging-2.json",
        f"results-{first.stem}-challenging.json",
        f"results-{second.stem}-challenging.json",
    ]


class FakeEvaluator:
    """Stands in for the Evaluator (`run` says what the episodes give)."""

    def __init__(self, spec):
        self.spec = spec

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()

    def close(self):
        pass


class ErringEvaluator(FakeEvaluator):
    """The first seed errs, the other episodes succeed."""

    def run(self, method, seeds, **options):
        return [
            EpisodeResult(
                seed=seed,
                success=index > 0,
                failure=None,
                error=None if index > 0 else "observation raised OSError: disk full",
            )
            for index, seed in enumerate(seeds)
        ]


def test_a_validation_round_with_errors_is_not_used_to_select_checkpoints(tmp_path, monkeypatch):
    monkeypatch.setattr(callback_module, "Evaluator", ErringEvaluator)
    callback = SuccessRateCallback(every_n_steps=2, episodes=3, cache_dir=None)
    checkpoint = ModelCheckpoint(
        dirpath=tmp_path / "checkpoints",
        monitor="eval/success_rate",
        mode="max",
        every_n_train_steps=2,
        save_top_k=-1,
    )
    trainer = pl.Trainer(
        max_steps=2,
        logger=TensorBoardLogger(tmp_path, name="logs"),
        callbacks=[callback, checkpoint],
        enable_progress_bar=False,
        enable_model_summary=False,
        accelerator="cpu",
    )
    trainer.fit(TinyStateMethod(), datamodule=TinyData())
    # 2 of the 3 validation seeds ran and succeeded; one erred
    events = EventAccumulator(trainer.logger.log_dir).Reload()
    assert events.Scalars("eval/errors")[0].value == 1.0
    assert events.Scalars("eval/episodes")[0].value == 2.0
    assert events.Scalars("eval/success_rate")[0].value == 1.0
    # ... but ModelCheckpoint saw no usable rate for this round
    assert math.isnan(trainer.callback_metrics["eval/success_rate"].item())
    # episodes without the strict check (None) give no strict rate, rather than a rate of 0
    assert "eval/strict_success_rate" not in events.Tags()["scalars"]


class MixedEvaluator(FakeEvaluator):
    """Every other episode succeeds, from the first."""

    def run(self, method, seeds, **options):
        return [
            EpisodeResult(seed=seed, success=index % 2 == 0, failure=None)
            for index, seed in enumerate(seeds)
        ]


def fit_with_a_round_of_three(tmp_path, monkeypatch, evaluator: type) -> pl.Trainer:
    """A 2-step fit whose one validation round of 3 episodes `evaluator` plays, logged to
    TensorBoard under `tmp_path`."""
    monkeypatch.setattr(callback_module, "Evaluator", evaluator)
    callback = SuccessRateCallback(every_n_steps=2, episodes=3, cache_dir=None)
    trainer = pl.Trainer(
        max_steps=2,
        logger=TensorBoardLogger(tmp_path, name="logs"),
        callbacks=[callback],
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        accelerator="cpu",
    )
    trainer.fit(TinyStateMethod(), datamodule=TinyData())
    return trainer


def test_validation_logs_the_rate_and_interval_of_a_mixed_round(tmp_path, monkeypatch):
    trainer = fit_with_a_round_of_three(tmp_path, monkeypatch, MixedEvaluator)
    metrics = trainer.callback_metrics
    assert metrics["eval/episodes"].item() == 3
    assert metrics["eval/success_rate"].item() == pytest.approx(2 / 3)
    low, high = wilson_interval(2, 3)
    assert metrics["eval/success_rate_low"].item() == pytest.approx(low)
    assert metrics["eval/success_rate_high"].item() == pytest.approx(high)


class StrictEvaluator(FakeEvaluator):
    """Every episode wins the anchor's reward, the first alone also the stricter 6-DoF check."""

    def run(self, method, seeds, **options):
        return [
            EpisodeResult(
                seed=seed,
                success=True,
                failure=None,
                strict_success=index == 0,
                strict_errors={"position_error": 0.002 if index == 0 else 0.02},
            )
            for index, seed in enumerate(seeds)
        ]


def test_validation_logs_the_strict_rate_beside_the_success_rate(tmp_path, monkeypatch):
    trainer = fit_with_a_round_of_three(tmp_path, monkeypatch, StrictEvaluator)
    events = EventAccumulator(trainer.logger.log_dir).Reload()
    assert events.Scalars("eval/success_rate")[0].value == 1.0
    assert events.Scalars("eval/strict_success_rate")[0].value == pytest.approx(1 / 3)
    low, high = wilson_interval(1, 3)
    assert events.Scalars("eval/strict_success_rate_low")[0].value == pytest.approx(low)
    assert events.Scalars("eval/strict_success_rate_high")[0].value == pytest.approx(high)


def test_the_results_file_records_the_strict_check(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(rollout_module, "Evaluator", StrictEvaluator)  # the test's, via Evaluators
    tester = pl.Trainer(
        logger=False,
        enable_progress_bar=False,
        accelerator="cpu",
        callbacks=[ClosedLoopTestCallback()],
    )
    metrics = tester.test(TinyStateMethod(), datamodule=TinyData())[0]
    (path,) = tmp_path.rglob("results-*.json")
    results = json.loads(path.read_text())
    assert [e["strict_success"] for e in results["episode_results"]] == [True, False]
    assert results["episode_results"][1]["strict_errors"] == {"position_error": 0.02}
    assert (results["successes"], results["strict_successes"]) == (2, 1)
    assert results["strict_success_rate"] == 0.5
    low, high = wilson_interval(1, 2)
    assert (results["strict_ci_low"], results["strict_ci_high"]) == pytest.approx((low, high))
    assert metrics["test/strict_success_rate"] == pytest.approx(0.5)
    assert "strict 6-DoF success: 50% (2, " in capsys.readouterr().out
