"""A tiny training run: rig data, the loss going down, checkpoint resume, weights_only loading, the CLI."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from lip_ros.core.skeleton import load_skeleton
from lip_ros.core.torch_kinematics import SkeletonTensors
from lip_ros.lip.nets.config import LipConfig
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.nets.models import LipNet
from lip_ros.lip.train.dataset import blank_frames, prepare
from lip_ros.lip.train.rigdata import TRAIN_SEEDS, VAL_SEEDS, generate, load_sequence, spec_for_seed
from lip_ros.lip.train.trainer import TrainOptions, evaluate, train
from lip_ros.tools import lip_train as cli

SECONDS = 5.0
pytestmark = pytest.mark.usefixtures("one_torch_thread")

CONFIG = LipConfig.tiny()
OPTIONS = TrainOptions(steps=30, batch=4, window=16, lr=3e-3, warmup=5, log_every=10, val_every=15)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """Three short rig sequences (two training, one validation), cached the way lip_train caches them."""
    d = tmp_path_factory.mktemp("rigdata")
    for seed in (*TRAIN_SEEDS[:2], VAL_SEEDS[0]):
        generate(spec_for_seed(seed, SECONDS), d)
    return d


@pytest.fixture(scope="module")
def prepared(data_dir):
    seqs = [load_sequence(generate(spec_for_seed(s, SECONDS), data_dir)) for s in (*TRAIN_SEEDS[:2], VAL_SEEDS[0])]
    train_set = [prepare(s, CONFIG.num_points, blank_frames(s.num_frames, np.random.default_rng(0))) for s in seqs[:2]]
    return train_set, [prepare(seqs[2], CONFIG.num_points)]


def test_rig_sequence_is_consistent(data_dir):
    seq = load_sequence(generate(spec_for_seed(TRAIN_SEEDS[0], SECONDS), data_dir))
    assert seq.num_frames == 50 and seq.offsets[-1] == len(seq.points) > 50
    assert seq.imu_rot.shape == (50, 4, 3, 3) and seq.imu_acc.shape == (50, 4, 3)
    centre = np.array([seq.frame_points(k).mean(0) for k in range(seq.num_frames)])
    assert np.linalg.norm(centre - seq.root_pos, axis=1).max() < 0.4  # the points are on the performer
    np.testing.assert_allclose(np.diff(seq.pose_time), 0.1, atol=0.02)


def test_loss_decreases_and_resume_is_exact(prepared, tmp_path):
    train_set, val_set = prepared
    skel = SkeletonTensors(load_skeleton())
    torch.manual_seed(OPTIONS.seed)
    before = evaluate(LipNet(CONFIG), val_set, skel)
    straight = train(CONFIG, train_set, val_set, OPTIONS, tmp_path / "a", log=lambda _: None)
    assert straight["loss"] < 0.7 * before["loss"]

    # interrupted half-way, then resumed to the end: the same weights
    train(CONFIG, train_set, val_set, replace(OPTIONS, stop_after=12), tmp_path / "b", log=lambda _: None)
    assert torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=True)["step"] == 12
    resumed = train(CONFIG, train_set, val_set, OPTIONS, tmp_path / "b", resume=True, log=lambda _: None)
    assert resumed == pytest.approx(straight, rel=1e-5)
    a = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=True)
    b = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=True)
    for k in a["model"]:
        torch.testing.assert_close(a["model"][k], b["model"][k], rtol=1e-5, atol=1e-6)

    best = torch.load(tmp_path / "a" / "best.pt", weights_only=True)
    assert LipModel.load(tmp_path / "a" / "best").net.state_dict().keys() == best.keys()


def test_resume_refuses_another_config(prepared, tmp_path):
    train_set, val_set = prepared
    opts = TrainOptions(steps=1, batch=2, window=16, val_every=1)
    train(CONFIG, train_set, val_set, opts, tmp_path, log=lambda _: None)
    with pytest.raises(ValueError, match="another config"):
        train(CONFIG.with_(trans_hidden=8), train_set, val_set, opts, tmp_path, resume=True, log=lambda _: None)


def test_cli_trains_and_exports(data_dir, tmp_path, capsys):
    status = cli.main(["--data-dir", str(data_dir), "--out", str(tmp_path / "run"), "--config", "tiny",
                       "--train-seqs", "2", "--val-seqs", "1", "--seconds", str(SECONDS), "--steps", "3",
                       "--batch", "2", "--window", "16", "--val-every", "3", "--export", str(tmp_path / "w" / "lip")])
    assert status == 0
    assert "final validation" in capsys.readouterr().out
    model = LipModel.load(tmp_path / "w" / "lip")
    assert model.config == CONFIG


def test_training_starts_from_given_weights(prepared, tmp_path):
    """``init``: with a zero learning rate the run ends where it started."""
    train_set, val_set = prepared
    torch.manual_seed(123)
    start = LipNet(CONFIG)
    opts = replace(OPTIONS, steps=3, lr=0.0, val_every=3)
    metrics = train(CONFIG, train_set, val_set, opts, tmp_path, init=start.state_dict(), log=lambda _: None)
    assert metrics == pytest.approx(evaluate(start, val_set, SkeletonTensors(load_skeleton())), rel=1e-5)


def test_fit_minutes_cuts_the_schedule(prepared, tmp_path):
    train_set, val_set = prepared
    logged: list[str] = []
    opts = replace(OPTIONS, steps=100_000, fit_minutes=1e-4, val_every=100_000)
    train(CONFIG, train_set, val_set, opts, tmp_path, log=logged.append)
    cut = [m for m in logged if m.startswith("schedule cut")]
    assert len(cut) == 1 and "from 100000 to 50 steps" in cut[0]  # nothing left after the 50 timed steps
    assert torch.load(tmp_path / "checkpoint.pt", weights_only=True)["step"] == 50
