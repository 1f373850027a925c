"""Training the learned detector stage: patches and targets, seeding, rt2 train's choice and its refusal to write a weak model."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="training needs rt2[train]")

from harness.cli import main  # noqa: E402
from harness.experiments.detector.coco import read_coco  # noqa: E402
from harness.experiments.detector.learned_train import (  # noqa: E402
    LearnedItem, LearnedTrainOptions, fit_learned, items_at_scale, max_side_for, sample_patches, targets)
from harness.experiments.detector.train import EXIT_WEAK_MODEL, load_image  # noqa: E402
from tracker import BallSegmentationModel  # noqa: E402


def test_targets_put_the_centre_in_its_cell_with_the_sub_cell_offset():
    heat, off, logd, mask = targets(np.array([[41.0, 22.5]]), np.array([10.0]), 64)
    # pixel 41 -> cell coordinate (41 + 0.5) / 4 - 0.5 = 9.875 -> cell 10, offset -0.125; 22.5 -> 5.25 -> cell 5, +0.25
    assert mask.sum() == 1 and mask[5, 10] == 1 and heat[5, 10] == 1.0
    np.testing.assert_allclose(off[:, 5, 10], [-0.125, 0.25])
    np.testing.assert_allclose(logd[5, 10], np.log(10.0), rtol=1e-6)
    assert heat[5, 11] < 1.0 and heat[5, 11] > 0.0 and heat[0, 0] < 1e-6
    empty = targets(np.zeros((0, 2)), np.zeros(0), 64)
    assert empty[0].max() == 0 and empty[3].sum() == 0
    outside = targets(np.array([[-30.0, 10.0]]), np.array([8.0]), 64)
    assert outside[3].sum() == 0  # a ball outside the patch leaves no centre


def test_patches_carry_their_balls_where_the_targets_say(synthetic_ball_coco):
    """Patches on a ball: the target's centre cell lies on the ball's bright pixels (without photometric changes)."""
    labelled = read_coco(synthetic_ball_coco(10, 0))
    items = items_at_scale([(load_image(li), li) for li in labelled], 640)
    opts = LearnedTrainOptions(patch_px=64, p_ball=1.0, augment=False, scale_range=(1.0, 1.0))
    imgs, heat, off, logd, mask = sample_patches(items, 12, np.random.default_rng(0), opts)
    assert imgs.shape == (12, 64, 64, 3) and heat.shape == (12, 16, 16)
    assert (mask.sum(axis=(1, 2)) >= 1).all()
    for im, m, o in zip(imgs, mask, off):
        r, c = np.argwhere(m)[0]
        u, v = (c + 0.5 + o[0, r, c]) * 4 - 0.5, (r + 0.5 + o[1, r, c]) * 4 - 0.5
        ball = im[int(round(v)), int(round(u))].astype(int)
        around = np.median(im.reshape(-1, 3), axis=0)
        assert np.abs(ball - around).sum() > 60  # the synthetic ball is a coloured disk on a textured background


def test_the_same_seed_gives_the_same_network_bytes(synthetic_ball_coco):
    labelled = read_coco(synthetic_ball_coco(10, 0))
    items = items_at_scale([(load_image(li), li) for li in labelled], 640)
    opts = LearnedTrainOptions(iterations=3, batch=4, patch_px=64)
    a = fit_learned(items, opts, 5, log=lambda m: None)[1]
    b = fit_learned(items, opts, 5, log=lambda m: None)[1]
    c = fit_learned(items, opts, 6, log=lambda m: None)[1]
    assert a == b and a != c


def test_the_patches_sampled_ahead_are_those_sampled_in_turn(synthetic_ball_coco, monkeypatch):
    """fit_learned samples the next batch on a second thread while it trains: every batch is the one a plain loop
    drawing from the same generator would give, in the same order (so a seed gives the same network as before)."""
    import harness.experiments.detector.learned_train as L

    labelled = read_coco(synthetic_ball_coco(10, 0))
    items = items_at_scale([(load_image(li), li) for li in labelled], 640)
    opts = LearnedTrainOptions(iterations=5, batch=4, patch_px=64)
    real, seen = L.sample_patches, []

    def recorded(*args, **kwargs):
        seen.append(real(*args, **kwargs))
        return seen[-1]

    monkeypatch.setattr(L, "sample_patches", recorded)
    fit_learned(items, opts, 3, log=lambda m: None)
    assert len(seen) == 5  # one per step, none sampled past the last
    rng = np.random.default_rng([3, 35])  # fit_learned's generator for seed 3
    for got in seen:
        for a, b in zip(got, real(items, 4, rng, opts)):
            np.testing.assert_array_equal(a, b)


def test_the_exported_graph_computes_the_torch_network():
    """The deployed ONNX graph (normalisation folded, head split) gives the torch module's output, both layouts,
    frames with odd and even cell counts; its initializers are the state dict as it was."""
    from harness.experiments.detector.learned_train import ARCHS, build_net, export_onnx, state_of_onnx
    from tracker.detection.learned import LearnedStage

    pytest.importorskip("onnx", reason="the export writes the graph with the onnx package (rt2[train])")
    rng = np.random.default_rng(0)
    for arch in ARCHS:
        torch.manual_seed(1)
        net = build_net(torch, arch=arch).eval()
        with torch.no_grad():
            for p in net.parameters():  # away from the initial head bias: every weight matters
                p.add_(0.1 * torch.randn_like(p))
        onnx_bytes = export_onnx(torch, net)
        stage = LearnedStage(onnx_bytes)
        for shape in [(36, 52), (44, 60), (80, 80), (52, 28), (240, 320)]:
            img = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
            with torch.no_grad():
                ref = net(torch.from_numpy(img[None])).numpy()[0]
            out = stage.run(img)
            assert out.shape == ref.shape, (arch, shape)
            np.testing.assert_allclose(out, ref, atol=2e-5, err_msg=f"{arch} {shape}")
        back = state_of_onnx(onnx_bytes)
        assert set(back) == set(net.state_dict())
        assert all(torch.equal(back[k], v) for k, v in net.state_dict().items())


def test_both_network_layouts_export_and_fine_tuning_keeps_the_layout_it_starts_from(synthetic_ball_coco):
    """s8 and s16 run on frames whose size is a whole number of cells but not of stride-16 cells; a stage of
    either layout fine-tunes (its state read back from the ONNX bytes) into a network of the same layout."""
    from harness.experiments.detector.learned_train import ARCHS, arch_of_state, build_net, export_onnx, state_of_onnx
    from tracker.detection.learned import LearnedStage

    pytest.importorskip("onnx", reason="fine-tuning reads the ONNX initializers back (rt2[train])")
    labelled = read_coco(synthetic_ball_coco(6, 0))
    items = items_at_scale([(load_image(li), li) for li in labelled], 640)
    for arch in ARCHS:
        torch.manual_seed(0)
        onnx_bytes = export_onnx(torch, build_net(torch, arch=arch))
        assert LearnedStage(onnx_bytes).run(np.zeros((36, 52, 3), np.uint8)).shape == (4, 9, 13)
        state = state_of_onnx(onnx_bytes)
        assert arch_of_state(state) == arch
        tuned, _ = fit_learned(items, LearnedTrainOptions(iterations=1, batch=2, patch_px=64, arch="s8" if arch == "s16" else "s16"),
                               0, state=state, log=lambda m: None)
        assert arch_of_state(tuned) == arch and set(tuned) == set(state)
    with pytest.raises(ValueError, match="arch"):
        LearnedTrainOptions(arch="s32")


def test_no_ball_nothing_to_learn():
    items = [LearnedItem(np.zeros((64, 64, 3), np.uint8), np.zeros((0, 2)), np.zeros(0))]
    with pytest.raises(ValueError, match="no ball"):
        fit_learned(items, LearnedTrainOptions(iterations=1), 0)


def test_max_side_shrinks_large_frames_towards_the_target_ball_size(synthetic_ball_coco):
    labelled = read_coco(synthetic_ball_coco(10, 0))
    assert max_side_for(labelled) == 128  # small frames are never enlarged
    assert max_side_for(labelled, 512) == 512
    from harness.experiments.detector.coco import LabelledImage

    rally_like = [LabelledImage(f"f{i}.jpg", 1920, 1080, np.array([[100.0, 100.0, 41.0, 41.0]]), np.array([[120.0, 120.0]])) for i in range(3)]
    assert max_side_for(rally_like) == 736  # 1920 * 16 / 41 = 749 -> a multiple of 32


def test_rt2_train_refuses_a_weak_model_with_exit_3_and_force_writes_it(synthetic_ball_coco, tmp_path, capsys):
    """Two optimiser steps cannot find a ball: recall < 50 % -> exit 3, one line, nothing written; --force writes it."""
    out = tmp_path / "m.npz"
    args = ["train", "--data", str(synthetic_ball_coco(12, 3)), "--out", str(out), "--epochs", "1", "--from", "none",
            "--learned", "on", "--learned-steps", "2", "--learned-folds", "2", "--thresholds", "cv", "--cv-folds", "2", "--seed", "0"]
    code = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    if code == 0:  # the filter's cross-validated recall decides only without a learned stage: this one must be weak
        pytest.fail(f"a learned stage of 2 steps was written: {err}")
    assert code == EXIT_WEAK_MODEL and not out.exists()
    said = [line for line in err if line.startswith("rt2 train:")]  # the rest of stderr is progress bars
    assert len(said) == 1 and said[0] == err[-1] and "not written" in said[0] and "< 50%" in said[0] and "--force" in said[0]
    assert main([*args, "--force"]) == 0 and out.is_file()
    assert "written anyway (--force)" in capsys.readouterr().err
    model = BallSegmentationModel.load(out)
    assert model.learned is not None and "learned stage: scratch" in model.description


def test_rt2_train_chooses_between_the_base_stage_fine_tuned_and_scratch(synthetic_ball_coco, tmp_path, capsys):
    """With a base model that has a stage, the three candidates are scored and the description says which won."""
    base_path = tmp_path / "base.npz"
    assert main(["train", "--data", str(synthetic_ball_coco(30, 0)), "--out", str(base_path), "--epochs", "1", "--from", "none",
                 "--learned", "on", "--learned-steps", "40", "--learned-folds", "2", "--force", "--seed", "0"]) == 0
    capsys.readouterr()
    out = tmp_path / "m.npz"
    assert main(["train", "--data", str(synthetic_ball_coco(12, 1)), "--out", str(out), "--epochs", "1", "--from", str(base_path),
                 "--learned-steps", "16", "--learned-folds", "2", "--force", "--seed", "0"]) == 0
    text = capsys.readouterr().out
    for name in ("shipped:", "fine-tuned:", "scratch:"):
        assert f"learned stage, 2-fold cross-validation on 12 images: {name}" in text
    model = BallSegmentationModel.load(out)
    assert "(of none, shipped, fine-tuned, scratch) by 2-fold cross-validation" in model.description


def test_the_filter_alone_is_a_choice_and_wins_over_a_weak_stage(synthetic_ball_coco, tmp_path, capsys):
    """``--learned auto`` scores the 5x5 filter alone (fitted without each held-out fold) beside the stages: a stage of two
    optimiser steps finds no ball, the filter alone does, so no stage is written and the figures printed are the
    filter's; ``--learned on`` writes the weak stage (and so is refused: exit 3)."""
    data = str(synthetic_ball_coco(12, 3))
    common = ["train", "--data", data, "--epochs", "2", "--from", "none", "--learned-steps", "2", "--learned-folds", "2",
              "--thresholds", "cv", "--cv-folds", "2", "--seed", "0"]
    out = tmp_path / "m.npz"
    assert main([*common, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    lines = [line for line in text.splitlines() if "learned stage, 2-fold cross-validation on 12 images" in line]
    assert [line.split(": ")[1] for line in lines] == ["none", "scratch"], lines
    none = float(lines[0].split("recall ")[1].split("%")[0])
    scratch = float(lines[1].split("recall ")[1].split("%")[0])
    assert none > 50.0 > scratch  # the filter finds these balls held out, two steps do not
    assert "learned stage: none written (the 5x5 filter alone scored best" in text
    assert "held-out figures of the model written (the filter alone, top-K" in text
    model = BallSegmentationModel.load(out)
    assert model.learned is None and "learned stage: none, the filter alone (of none, scratch)" in model.description
    assert main([*common, "--learned", "on", "--out", str(tmp_path / "on.npz")]) == EXIT_WEAK_MODEL
    assert not (tmp_path / "on.npz").exists()


def test_a_base_whose_filter_does_not_see_its_ball_keeps_its_filter(synthetic_ball_coco, tmp_path, capsys):
    """``--filter auto`` with a base whose stage the filter does not refine (the shipped white model's case): the 5x5
    filter is written unchanged (no filter fit: minutes saved), the learned stage is trained and chosen as always, and
    the output names both; ``--filter fit`` fits the filter anyway."""
    import dataclasses

    base_path = tmp_path / "base.npz"
    assert main(["train", "--data", str(synthetic_ball_coco(30, 0)), "--out", str(base_path), "--epochs", "1", "--from", "none",
                 "--learned", "on", "--learned-steps", "40", "--learned-folds", "2", "--force", "--seed", "0"]) == 0
    base = BallSegmentationModel.load(base_path)
    other = tmp_path / "other.npz"  # its filter "of another ball": the stage says the filter does not refine it
    dataclasses.replace(base, learned=dataclasses.replace(base.learned, filter_refines=False)).save(other)
    capsys.readouterr()
    out = tmp_path / "m.npz"
    data = str(synthetic_ball_coco(12, 1))
    common = ["train", "--data", data, "--from", str(other), "--learned-steps", "16", "--learned-folds", "2", "--force", "--seed", "0"]
    assert main([*common, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "the 5x5 filter: the base model's kept unchanged" in text and "epoch" not in text  # no filter fit
    assert "held-out figures of the model written (the learned stage" in text and "the base model's 5x5 filter kept" in text
    line = next(ln for ln in text.splitlines() if ln.startswith("held-out figures of the model written"))
    assert "): top-4 recall " in line and "; single images (each image's best candidate at threshold " in line  # named by what they count
    m = BallSegmentationModel.load(out)
    single_th = float(line.split("best candidate at threshold ")[1].split(")")[0])
    assert m.learned.threshold == pytest.approx(single_th)  # the file's single-image threshold is the one its figures are at
    assert m.learned.track_threshold <= 0.2  # the tracker's own, chosen top-K (at most TRACK_THRESHOLD)
    np.testing.assert_array_equal(m.kernel, base.kernel)
    assert (m.t_high, m.t_low, m.bias) == (base.t_high, base.t_low, base.bias) and m.learned is not None
    assert not m.learned.filter_refines  # the stage still says so
    assert "5x5 filter kept unchanged" in m.description
    fit = tmp_path / "fit.npz"
    assert main([*common, "--out", str(fit), "--filter", "fit", "--epochs", "1"]) == 0
    assert "the base model's kept unchanged" not in capsys.readouterr().out


def test_which_filter_train_keeps():
    import dataclasses

    from harness.experiments.detector.train import TrainOptions, keeps_filter
    from tracker.detection.learned import LearnedStage

    class Stage:  # what keeps_filter reads of a base's stage
        def __init__(self, refines):
            self.filter_refines = refines

    class Base:
        def __init__(self, learned):
            self.learned = learned

    auto = TrainOptions(learned="auto")
    assert keeps_filter(auto, Base(Stage(False)))
    assert not keeps_filter(auto, Base(Stage(True)))  # the filter sees the stage's ball: it is fitted
    assert not keeps_filter(auto, Base(None)) and not keeps_filter(auto, None)
    assert not keeps_filter(dataclasses.replace(auto, learned="off"), Base(Stage(False)))  # the filter is all that is trained
    assert not keeps_filter(dataclasses.replace(auto, filter="fit"), Base(Stage(False)))
    assert keeps_filter(dataclasses.replace(auto, filter="keep"), Base(Stage(True)))
    for bad, message in ((dict(filter="maybe"), "TrainOptions.filter must be one of"),
                         (dict(filter="keep", learned="off"), "trains nothing")):
        with pytest.raises(ValueError, match=message):
            TrainOptions(**{"learned": "auto", **bad})
    assert "filter_refines" in {f.name for f in dataclasses.fields(LearnedStage)}  # the real stage has what keeps_filter reads


def test_learned_options_hostile(synthetic_ball_coco, tmp_path, capsys):
    data = str(synthetic_ball_coco(12, 3))
    for extra, message in ((["--learned", "maybe"], "invalid choice"), (["--learned-steps", "0"], "--learned-steps must be a positive integer, got 0"),
                           (["--learned-folds", "1"], "--learned-folds must be an integer >= 2, got 1"), (["--filter", "maybe"], "invalid choice"),
                           (["--filter", "keep", "--learned", "off"], "--filter keep with --learned off trains nothing"),
                           (["--filter", "keep", "--from", "none"], "there is no base model"),
                           (["--learned-mined", "1.5"], "--learned-mined must be 'auto' or a share between 0 and 1"),
                           (["--learned-mined", "-0.1"], "--learned-mined must be 'auto' or a share between 0 and 1"),
                           (["--learned-mined", "nan"], "--learned-mined must be 'auto' or a share between 0 and 1"),
                           (["--learned-mined", "maybe"], "must be 'auto' or a share between 0 and 1, got 'maybe'"),
                           (["--workers", "0"], "--workers must be an integer >= 1, got 0"),
                           (["--workers", "-2"], "--workers must be an integer >= 1, got -2"),
                           (["--workers", "two"], "argument --workers: invalid int value: 'two'")):
        with pytest.raises(SystemExit) if extra[-1] in ("maybe", "two") else _no_raise():
            code = main(["train", "--data", data, "--out", str(tmp_path / "m.npz"), *extra])
            assert code == 2
        err = capsys.readouterr().err
        assert message in err
        assert not (tmp_path / "m.npz").exists()


class _no_raise:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _twelve_images_and_a_network(synthetic_ball_coco):
    """12 labelled synthetic images and a heatmap network fitted on them for 4 steps (a base stage's network)."""
    labelled = read_coco(synthetic_ball_coco(12, 1))
    images = [load_image(li) for li in labelled]
    _, onnx = fit_learned(items_at_scale(list(zip(images, labelled)), 128), LearnedTrainOptions(iterations=4, batch=4, patch_px=32, max_side_px=128), 0,
                          log=lambda m: None)
    return labelled, images, onnx


def _record_stages(monkeypatch) -> list:
    """The learned stages :mod:`learned_train` makes from now on, in order (a list it fills)."""
    from harness.experiments.detector import learned_train as L
    from tracker.detection.learned import LearnedStage

    made = []

    class Recording(LearnedStage):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    monkeypatch.setattr(L, "LearnedStage", Recording)
    return made


def test_a_fine_tune_keeps_its_base_coarse_pass_in_cross_validation_and_in_the_file(synthetic_ball_coco, monkeypatch):
    """A fine-tuned stage is the base's network a little changed: it searches full frames in the base's two passes
    (scored so in the cross-validation, written so); a stage from scratch has one pass."""
    from harness.experiments.detector import learned_train as L
    from harness.experiments.detector.train import cv_folds
    from tracker.detection.learned import LearnedStage

    labelled, images, onnx = _twelve_images_and_a_network(synthetic_ball_coco)
    base = LearnedStage(onnx, max_side_px=128, threshold=0.5, coarse_side_px=64, coarse_threshold=0.15, coarse_candidates=5)
    made = _record_stages(monkeypatch)
    monkeypatch.setattr(L.StageChoice, "gain", property(lambda c: 1.0 if c.name == "fine-tuned" else 0.0))  # the fine-tune wins
    lines = []
    stage, info = L.train_stage(labelled, images, cv_folds(labelled, 2), base=base, seed=0, finetune_steps=3, scratch_steps=3, batch=4,
                                patch_px=32, log=lines.append)
    assert info["chosen"].name == "fine-tuned"
    assert any(line.startswith("learned stage: fine-tuned with ") and "contrast crops" in line for line in lines)
    assert (stage.coarse_side_px, stage.coarse_threshold, stage.coarse_candidates) == (64, 0.15, 5)
    assert stage.onnx != base.onnx
    # the cross-validation's stages: two folds x (fine-tuned with the coarse pass, scratch without), then the file's
    assert [s.coarse_side_px for s in made] == [64, 0, 64, 0, 64]
    assert L.kept_passes("scratch", base) == {} and L.kept_passes("fine-tuned", None) == {}  # a base without a confirmation network


@pytest.mark.parametrize("winner", ["shipped", "fine-tuned", "scratch"])
def test_a_trained_stage_keeps_its_bases_confirmation_network_with_the_threshold_chosen_for_it(synthetic_ball_coco, monkeypatch, winner):
    """The confirmation network looks at crops, not at the heat network: every stage keeps it, the base as it is,
    fine-tuned and one from scratch, in the cross-validation (whose scores are then the confirmed ones) and in the file,
    where the single image's threshold chosen is the confirmation's; the heat keeps the base's threshold, a stage from
    scratch the top-K one chosen for it."""
    import torch

    from harness.experiments.detector import learned_train as L
    from harness.experiments.detector.confirm_train import CROP_PX, confirm_net, export_confirm
    from harness.experiments.detector.train import cv_folds
    from tracker.detection.confirm import ConfirmNet
    from tracker.detection.learned import LearnedStage

    labelled, images, onnx = _twelve_images_and_a_network(synthetic_ball_coco)
    torch.manual_seed(0)
    confirm = ConfirmNet(export_confirm(torch, confirm_net(torch).eval(), CROP_PX), threshold=0.45)
    base = LearnedStage(onnx, max_side_px=128, threshold=0.35, confirm=confirm)
    made = _record_stages(monkeypatch)
    monkeypatch.setattr(L.StageChoice, "gain", property(lambda c: 1.0 if c.name == winner else 0.0))
    stage, info = L.train_stage(labelled, images, cv_folds(labelled, 2), base=base, seed=0, finetune_steps=3, scratch_steps=3, batch=4,
                                patch_px=32, log=lambda m: None)
    assert info["chosen"].name == winner
    assert [s.confirm is confirm for s in made[:4]] == [True, True, True, True]  # the folds' fine-tunes and stages from scratch
    assert stage.confirm.onnx == confirm.onnx and stage.confirm.threshold == info["single_threshold"]
    assert stage.threshold == (info["chosen"].threshold if winner == "scratch" else 0.35)
    points = L.operating_points("scratch", base, 0.2, 0.3)
    assert points["threshold"] == 0.3 and points["confirm"].onnx == confirm.onnx and points["confirm"].threshold == 0.2
    plain = dataclasses.replace(base, confirm=None)
    assert L.operating_points("scratch", plain, 0.2, 0.3) == {"threshold": 0.2} and L.kept_passes("scratch", plain) == {}
    with pytest.raises(ValueError, match="needs its top-K threshold"):
        L.operating_points("scratch", base, 0.2)


def test_contrast_crops_are_the_bases_false_candidates_next_to_a_ball():
    """A crop around each false candidate of the base (off every ball, heat >= CONTRAST_MIN_HEAT) that holds a
    labelled ball, with the ball's label at the crop's pixels; candidates on a ball, too weak, or with no ball near
    make none; with_contrast gives the crops CONTRAST_SHARE of the patches."""
    from pathlib import Path

    from harness.experiments.detector import learned_train as L
    from harness.experiments.detector.coco import LabelledImage

    img = np.zeros((400, 600, 3), np.uint8)
    li = LabelledImage(Path("x.png"), 600, 400, np.array([[290.0, 190.0, 20.0, 20.0]]), np.array([[299.5, 199.5]]))
    item = items_at_scale([(img, li)], 300)[0]  # half scale: the ball at (149.5, 99.5), 10 px
    assert item.image.shape[:2] == (200, 300)
    uv = np.array([[300.0, 200.0], [360.0, 180.0], [40.0, 40.0], [330.0, 230.0]])  # on the ball, next to it, far, weak
    sc = np.array([0.9, 0.5, 0.6, 0.05])
    crops = L.contrast_crops([item], [(uv, sc)], [li], [0])
    assert len(crops) == 1
    c = crops[0]
    x, y = (360.0 + 0.5) * 0.5 - 0.5, (180.0 + 0.5) * 0.5 - 0.5  # the false candidate at the network's scale
    x0, y0 = int(max(0, x - L.CONTRAST_HALF_PX)), int(max(0, y - L.CONTRAST_HALF_PX))
    np.testing.assert_allclose(c.centers, item.centers - [x0, y0])
    np.testing.assert_allclose(c.diameters, item.diameters)
    assert c.image.shape[1] == int(min(300, x + L.CONTRAST_HALF_PX)) - x0
    assert L.contrast_crops([item], [(uv, sc)], [li], []) == []  # only the images asked for (a fold's training part)
    rest = [item, LearnedItem(img[:64, :64], np.zeros((0, 2)), np.zeros(0), 0.5)]
    mixed = L.with_contrast(rest, crops * 2)
    w_crops = sum(it.weight for it in mixed[2:])
    assert w_crops / sum(it.weight for it in mixed) == pytest.approx(L.CONTRAST_SHARE)
    assert L.with_contrast(rest, []) == rest


def test_single_image_scores_count_each_image_s_best_candidate_only():
    """``rt2 train``'s single-image figures (with a learned stage): the best candidate at the threshold, not the first K."""
    from harness.experiments.detector.learned_train import _scores_at

    truth = ([np.array([[10.0, 10.0]]), np.array([[50.0, 50.0]]), np.zeros((0, 2))], [np.array([8.0]), np.array([8.0]), np.zeros(0)])
    cands = [(np.array([[30.0, 30.0], [10.0, 11.0]]), np.array([0.9, 0.8])),  # a false alarm above the ball: an outlier, the ball missed
             (np.array([[50.0, 51.0], [90.0, 90.0]]), np.array([0.7, 0.6])),  # the ball first
             (np.array([[5.0, 5.0]]), np.array([0.3]))]  # no ball, a candidate below the threshold
    s = _scores_at(truth, cands, 0.5, 1, 6.0)
    assert (s.n_balls, s.n_detections) == (2, 2)
    assert s.recall == pytest.approx(0.5) and s.outlier_rate == pytest.approx(0.5)
    assert _scores_at(truth, cands, 0.95, 1, 6.0).n_detections == 0


def test_single_images_get_a_threshold_of_their_own():
    """The written stage's single-image threshold is the best for each image's first candidate up to the top-K one (the
    tracker's, which chooses the stage): lower where the false candidates rank after the ball, never higher (a lamp that
    outranks the ball in the labelled cameras would take every other camera's balls with it), and the top-K one where
    no threshold finds more balls than false ones."""
    from harness.experiments.detector.learned_train import _best_threshold, single_image_threshold

    ball = lambda u: np.array([[u, u]])  # noqa: E731
    truth = ([ball(10.0), ball(50.0), ball(90.0), np.zeros((0, 2))], [np.array([8.0])] * 3 + [np.zeros(0)])
    weak = [(np.array([[10.0, 10.0], [300.0, 300.0]]), np.array([0.25, 0.22])),  # a weak ball, a weaker alarm after it
            (np.array([[50.0, 50.0]]), np.array([0.45])),
            (np.array([[90.0, 90.0], [200.0, 200.0]]), np.array([0.45, 0.21])),
            (np.zeros((0, 2)), np.zeros(0))]
    top4_th, top4 = _best_threshold(truth, weak, 4, 6.0)
    assert top4_th == 0.4 and top4.recall == pytest.approx(2 / 3)  # the alarms after the balls cost the weak ball
    th, single, kept = single_image_threshold(truth, weak, top4_th, 6.0)
    assert th == 0.2 and single.recall == 1.0 and single.outlier_rate == 0 and not kept  # a first candidate has no alarm
    above = [(np.array([[10.0, 10.0]]), np.array([0.45])),
             (np.array([[50.0, 50.0]]), np.array([0.45])),
             (np.array([[300.0, 300.0], [90.0, 90.0]]), np.array([0.35, 0.25])),  # an alarm above a weak ball
             (np.array([[200.0, 200.0]]), np.array([0.12]))]  # a weak alarm in a ball-free image
    top4_th, _ = _best_threshold(truth, above, 4, 6.0)
    assert top4_th == 0.2 and _best_threshold(truth, above, 1, 6.0)[0] == 0.4  # alone, the single image's would be higher
    th, single, kept = single_image_threshold(truth, above, top4_th, 6.0)
    assert th == 0.2 and single.recall == pytest.approx(2 / 3) and not kept  # capped at the top-K one
    # a lamp above the ball in every image: no threshold up to the top-K one finds more balls than alarms
    lamp = [(np.array([[400.0, 400.0], *c[0]]), np.array([0.8, *c[1]])) for c in above]
    assert _best_threshold(truth, lamp, 1, 6.0)[0] == 0.9  # (finding nothing scores best)
    th, s, kept = single_image_threshold(truth, lamp, 0.2, 6.0)
    assert (th, kept, s.recall) == (0.2, True, 0.0) and s.n_detections == 4


def _named(n_cams: int, per_cam: int = 4, camera_field: bool = True):
    from harness.experiments.detector.coco import LabelledImage

    return [LabelledImage(f"/data/f{t:06d}_{'cameras.' if camera_field else 'cam'}{c}.png", 64, 48, np.array([[10.0, 10.0, 8.0, 8.0]]),
                          np.array([[13.5, 13.5]]), camera=f"cameras.{c}" if camera_field else None)
            for t in range(per_cam) for c in range(n_cams)]


def test_a_rigs_labels_fold_by_camera_and_one_cameras_by_time():
    """``--learned-folds-by auto``: the labels of three or more named cameras (rt2 label --auto's) fold by whole cameras,
    each fit scored on cameras it never saw; fewer cameras, or images without one, fold by time."""
    from harness.experiments.detector.train import camera_folds, cv_folds, learned_folds

    three = _named(3)
    folds, by = learned_folds(three, 3)
    assert by == "camera" and len(folds) == 3
    for f in folds:
        assert len({three[i].camera for i in f}) == 1 and len(f) == 4
    assert sorted(i for f in folds for i in f) == list(range(12))
    folds, by = learned_folds(_named(4), 3)  # four cameras in three folds: one fold holds two
    assert by == "camera" and sorted(len(f) for f in folds) == [4, 4, 8]
    assert learned_folds(_named(3, camera_field=False), 3)[1] == "camera"  # the camera from the file name (f000001_cam2.png)
    two = _named(2)
    folds, by = learned_folds(two, 3)
    assert by == "time" and folds == cv_folds(two, 3)
    assert learned_folds(three, 3, "time") == (cv_folds(three, 3), "time")
    assert learned_folds(two, 3, "camera")[1] == "camera" and len(camera_folds(two, 3)) == 2


@pytest.mark.parametrize("labelled, by, message", [
    (_named(1), "camera", "--learned-folds-by camera needs images of at least 2 cameras, got cameras.0"),
    ([*_named(2), *[li.__class__(f"/data/other_{i}.png", 64, 48, li.boxes_xywh, li.centers_px) for i, li in enumerate(_named(1))]],
     "camera", "--learned-folds-by camera needs every image's camera"),
    (_named(3), "sideways", "learned folds by must be one of"),
])
def test_folds_by_camera_refuse_what_they_cannot_fold(labelled, by, message):
    from harness.experiments.detector.train import learned_folds

    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        learned_folds(labelled, 3, by)


def test_rt2_train_folds_a_rigs_labels_by_camera(synthetic_ball_coco, tmp_path, capsys):
    """rt2 train on labels of three named cameras: its learned stage's cross-validation folds by camera (the line says
    which cameras each fold holds, the model's description says so); ``--learned-folds-by camera`` on one camera's
    labels is one line, exit 2, before any training."""
    from harness.experiments.detector.coco import write_coco

    src = read_coco(synthetic_ball_coco(12, 3))
    rig = tmp_path / "rig"
    rig.mkdir()
    named = []
    for i, li in enumerate(src):
        path = rig / f"f{i // 3:06d}_cam{i % 3}.png"
        path.write_bytes(li.path.read_bytes())
        named.append(li.__class__(path, li.width, li.height, li.boxes_xywh, li.centers_px, camera=f"cameras.{i % 3}"))
    write_coco(rig, named, image_extra=[{"camera": li.camera} for li in named])  # the field rt2 label --auto writes
    out = tmp_path / "m.npz"
    common = ["train", "--data", str(rig), "--epochs", "1", "--from", "none", "--learned", "on", "--learned-steps", "2",
              "--thresholds", "cv", "--cv-folds", "2", "--force", "--seed", "0"]
    assert main([*common, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "learned stage: 3 cross-validation folds by camera (cameras.0; cameras.1; cameras.2)" in text
    assert "(folds by camera)" in BallSegmentationModel.load(out).description
    one = str(synthetic_ball_coco(12, 3))
    assert main([*common, "--data", one, "--learned-folds-by", "camera", "--out", str(tmp_path / "one.npz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--learned-folds-by camera needs images of at least 2 cameras, got cam0" in err[0]
    assert not (tmp_path / "one.npz").exists()


def test_a_drawn_light_is_saturated_and_covers_no_ball():
    from harness.experiments.detector.learned_train import draw_light

    rng = np.random.default_rng(3)
    base = np.random.default_rng(1).integers(40, 140, (96, 96, 3), dtype=np.uint8)
    ball_c, ball_d = np.array([[48.0, 48.0]]), np.array([12.0])
    yy, xx = np.mgrid[0:96, 0:96]
    on_ball = np.hypot(xx - 48, yy - 48) <= 6
    drawn = 0
    for _ in range(40):
        out = draw_light(base, rng, ball_c, ball_d)
        assert out.dtype == np.uint8 and out.shape == base.shape
        assert (out[on_ball] == base[on_ball]).all()  # never over a ball
        if (out != base).any():
            drawn += 1
            assert (out >= 215).all(axis=2).sum() >= 4  # a clipped core (one channel may sit under the clip)
    assert drawn >= 20
    assert draw_light(base, rng, np.array([[48.0, 48.0]]), np.array([400.0])) is base  # nowhere to put it


def test_p_light_draws_lights_only_when_asked(synthetic_ball_coco, monkeypatch):
    import harness.experiments.detector.learned_train as L

    labelled = read_coco(synthetic_ball_coco(10, 0))
    items = items_at_scale([(load_image(li), li) for li in labelled], 640)
    lit = sample_patches(items, 8, np.random.default_rng(0), LearnedTrainOptions(patch_px=64, p_light=1.0))

    def never(*args, **kwargs):
        raise AssertionError("a light drawn with p_light 0")

    monkeypatch.setattr(L, "draw_light", never)
    plain = sample_patches(items, 8, np.random.default_rng(0), LearnedTrainOptions(patch_px=64))  # p_light 0: no light
    assert (lit[0] != plain[0]).any() and ((lit[0] == 255).all(axis=3).sum() > (plain[0] == 255).all(axis=3).sum())
    for bad in (-0.1, 1.5, True, "0.3"):
        with pytest.raises(ValueError, match="p_light must be a share between 0 and 1"):
            LearnedTrainOptions(p_light=bad)


def test_a_faded_ball_keeps_its_place_at_a_fraction_of_its_contrast():
    import cv2

    from harness.experiments.detector.learned_train import FADE_CONTRAST, fade_balls

    base = np.random.default_rng(1).integers(50, 70, (96, 96, 3), dtype=np.uint8)
    cv2.circle(base, (40, 50), 8, (235, 235, 235), -1)  # a ball 17 px across on a dark, noisy floor
    yy, xx = np.mgrid[0:96, 0:96]
    dist = np.hypot(xx - 40, yy - 50)
    rng = np.random.default_rng(3)
    for _ in range(20):
        out = fade_balls(base, rng, np.array([[40.0, 50.0]]), np.array([17.0]))
        assert out.dtype == np.uint8 and out.shape == base.shape and out is not base
        assert (out[dist > 11.5] == base[dist > 11.5]).all()  # nothing beyond the ball and its feathered pixel
        contrast = (out[dist <= 6].mean() - 60.0) / (base[dist <= 6].mean() - 60.0)
        assert FADE_CONTRAST[0] - 0.06 <= contrast <= FADE_CONTRAST[1] + 0.06
        assert out[dist <= 6].mean() > out[(dist > 12) & (dist < 20)].mean() + 40  # still a ball brighter than its floor
    assert (base[dist <= 6] == 235).all()  # the patch itself untouched
    off = np.array([[400.0, 400.0]])
    assert fade_balls(base, rng, off, np.array([17.0])) is base  # no ball in the patch: nothing to fade


def test_p_faded_fades_balls_only_when_asked(synthetic_ball_coco, monkeypatch):
    import harness.experiments.detector.learned_train as L

    labelled = read_coco(synthetic_ball_coco(10, 0))
    items = items_at_scale([(load_image(li), li) for li in labelled], 640)
    calls = []
    real = L.fade_balls
    monkeypatch.setattr(L, "fade_balls", lambda *a: calls.append(1) or real(*a))
    opts = dict(patch_px=64, p_ball=1.0, augment=False)
    changed = 0
    for seed in range(8):  # one patch a draw: its place is drawn before the fading, so its targets are the plain one's
        faded = sample_patches(items, 1, np.random.default_rng(seed), LearnedTrainOptions(p_faded=1.0, **opts))
        plain = sample_patches(items, 1, np.random.default_rng(seed), LearnedTrainOptions(**opts))  # p_faded 0: no draw
        assert len(calls) == seed + 1
        changed += bool((faded[0] != plain[0]).any())
        for a, b in zip(faded[1:], plain[1:]):  # the targets stay the balls'
            assert np.array_equal(a, b)
    assert changed >= 6  # a ball cut by the patch's edge may keep its pixels
    for bad in (-0.1, 1.5, True, "0.3"):
        with pytest.raises(ValueError, match="p_faded must be a share between 0 and 1"):
            LearnedTrainOptions(p_faded=bad)


class _BrightnessNet(torch.nn.Module):
    """A stand-in network with a known heat: each 4x4 cell's mean brightness (255 -> logit +6, 0 -> -6), offsets 0."""

    training = True

    def forward(self, image):
        x = image.permute(0, 3, 1, 2).float().mean(1, keepdim=True) / 255.0
        heat = torch.nn.functional.avg_pool2d(x, 4) * 12.0 - 6.0
        return torch.cat([heat, torch.zeros_like(heat).repeat(1, 3, 1, 1)], 1)


def test_mined_false_peaks_are_the_networks_alarms_away_from_the_balls():
    from harness.experiments.detector.learned_train import MINE_PER_IMAGE, mine_false_peaks

    img = np.zeros((64, 96, 3), np.uint8)
    img[20:24, 40:44] = 255  # a bright cell: the labelled ball
    img[40:44, 8:12] = 255  # another: a false alarm at (9.5, 41.5)
    img[8:12, 80:84] = 120  # dimmer, still over MINE_HEAT (sigmoid(120/255*12-6) ~ 0.43): a second alarm
    items = [LearnedItem(img, np.array([[41.5, 21.5]]), np.array([4.0])), LearnedItem(np.zeros((30, 50, 3), np.uint8), np.zeros((0, 2)), np.zeros(0))]
    net = _BrightnessNet()
    mined = mine_false_peaks(torch, net, items)
    # the second image (odd size, padded to whole cells) has no alarm; the first's are in order of heat, never the ball
    assert [m[0] for m in mined] == [0, 0]
    np.testing.assert_allclose([m[1:] for m in mined], [[9.5, 41.5], [81.5, 9.5]])
    assert net.training  # left as it was found
    many = np.zeros((64, 96, 3), np.uint8)
    for k in range(MINE_PER_IMAGE + 3):
        many[4:8, 8 * k + 4:8 * k + 8] = 200 + 5 * k
    mined = mine_false_peaks(torch, net, [LearnedItem(many, np.zeros((0, 2)), np.zeros(0))])
    assert len(mined) == MINE_PER_IMAGE and mined[0][1] == pytest.approx(8 * (MINE_PER_IMAGE + 2) + 5.5)  # the brightest first


def test_patches_near_mined_alarms_only_when_asked(synthetic_ball_coco):
    """With ``p_mined`` 1 every patch is centred near a mined alarm; with none mined yet the patches are those of a
    sampler without mining, bit for bit (no random draw)."""
    labelled = read_coco(synthetic_ball_coco(10, 0))
    items = items_at_scale([(load_image(li), li) for li in labelled], 640)
    base = sample_patches(items, 8, np.random.default_rng(0), LearnedTrainOptions(patch_px=64))
    none_yet = sample_patches(items, 8, np.random.default_rng(0), LearnedTrainOptions(patch_px=64, p_mined=0.5), mined=())
    for a, b in zip(base, none_yet):
        np.testing.assert_array_equal(a, b)
    img = np.zeros((240, 320, 3), np.uint8)
    img[100:108, 200:208] = (0, 255, 0)  # the alarm: a green square, the only green in the image
    marked = [LearnedItem(img, np.zeros((0, 2)), np.zeros(0))] + items
    opts = LearnedTrainOptions(patch_px=64, p_mined=1.0, augment=False, scale_range=(1.0, 1.0))
    imgs = sample_patches(marked, 6, np.random.default_rng(1), opts, mined=((0, 203.5, 103.5),))[0]
    for im in imgs:
        ys, xs = np.nonzero((im[..., 1] > 200) & (im[..., 0] < 50))
        assert len(ys), "a patch drawn near the mined alarm does not hold it"
        assert abs(xs.mean() - 31.5) <= 0.3 * 64 + 1 and abs(ys.mean() - 31.5) <= 0.3 * 64 + 1
    for bad in (-0.1, 1.5, True, "0.3"):
        with pytest.raises(ValueError, match="p_mined must be a share between 0 and 1"):
            LearnedTrainOptions(p_mined=bad)
    with pytest.raises(ValueError, match="mine_every must be a positive integer"):
        LearnedTrainOptions(mine_every=0)


def test_the_weights_moving_average_is_kept_when_asked(synthetic_ball_coco, monkeypatch):
    """``ema``: the network written is the exponential moving average of its weights over the steps (each step's
    weights averaged in as torch's AveragedModel does), not the last step's; 0 keeps the last step's; repeatable."""
    import torch

    from harness.experiments.detector.learned_train import build_net

    labelled = read_coco(synthetic_ball_coco(6, 0))
    items = items_at_scale([(load_image(li), li) for li in labelled], 640)
    opts = LearnedTrainOptions(iterations=12, batch=4, patch_px=64)
    lines = []
    last, last_onnx = fit_learned(items, opts, 3, log=lambda m: None)
    avg, avg_onnx = fit_learned(items, dataclasses.replace(opts, ema=0.9), 3, log=lines.append)
    assert fit_learned(items, dataclasses.replace(opts, ema=0.9), 3, log=lambda m: None)[1] == avg_onnx
    assert avg_onnx != last_onnx and "moving average kept (decay 0.9 per step)" in lines[-1]
    # the average by hand, from the same run's weights after each step
    seen = []
    original = torch.optim.Adam.step

    def step(self, *a, **k):
        out = original(self, *a, **k)
        seen.append([p.detach().clone() for g in self.param_groups for p in g["params"]])
        return out

    monkeypatch.setattr(torch.optim.Adam, "step", step)
    fit_learned(items, dataclasses.replace(opts, ema=0.9), 3, log=lambda m: None)
    expected = seen[0]
    for w in seen[1:]:
        expected = [0.9 * e + 0.1 * x for e, x in zip(expected, w)]
    names = [n for n, _ in build_net(torch).named_parameters()]
    for name, e in zip(names, expected):
        np.testing.assert_allclose(avg[name].numpy(), e.numpy(), rtol=1e-5, atol=1e-6)
    assert not np.allclose(last["head.weight"].numpy(), avg["head.weight"].numpy())
    for bad in (-0.1, 1.0, True, "0.9", float("nan")):
        with pytest.raises(ValueError, match="ema must be a decay per step from 0"):
            LearnedTrainOptions(ema=bad)


def test_mining_during_training_is_logged_and_repeatable(synthetic_ball_coco):
    labelled = read_coco(synthetic_ball_coco(10, 0))
    items = items_at_scale([(load_image(li), li) for li in labelled], 640)
    opts = LearnedTrainOptions(iterations=24, batch=4, patch_px=64, p_mined=0.5, mine_every=8)
    lines = []
    _, a = fit_learned(items, opts, 3, log=lines.append)
    _, b = fit_learned(items, opts, 3, log=lambda m: None)
    assert a == b
    assert [ln.split(",")[0] for ln in lines if "mined" in ln] == ["learned stage: step 8", "learned stage: step 16"]


def test_rt2_train_mines_the_stages_false_alarms_only_when_asked(synthetic_ball_coco, tmp_path, monkeypatch):
    """``--learned-mined F``: every fit of the learned stage (the cross-validation's and the file's, fine-tuned and
    from scratch) draws F of its patches near its own false alarms, mined at a third and two thirds of its steps;
    without it none does."""
    import harness.experiments.detector.learned_train as L

    seen = []
    real_fit = L.fit_learned

    def recording_fit(items, opts, seed, **kw):
        seen.append((opts.iterations, opts.p_mined, opts.mine_every))
        return real_fit(items, opts, seed, **kw)

    monkeypatch.setattr(L, "fit_learned", recording_fit)
    data = str(synthetic_ball_coco(12, 3))
    common = ["train", "--data", data, "--learned", "on", "--learned-steps", "9", "--filter", "keep", "--force"]
    assert main([*common, "--learned-mined", "0", "--out", str(tmp_path / "plain.npz")]) in (0, 3)
    assert seen and all(p == 0.0 for _, p, _ in seen)
    seen.clear()
    assert main([*common, "--learned-mined", "0.3", "--out", str(tmp_path / "mined.npz")]) in (0, 3)
    assert len(seen) >= 3 and all(p == 0.3 and every == -(-steps // 3) for steps, p, every in seen)
    written = BallSegmentationModel.load(tmp_path / "mined.npz")
    assert "30 % of its patches near its own false alarms" in written.learned.description


@pytest.mark.parametrize("first_outliers, alarms, mined_gain, expect_calls, expect_kept", [
    (0.5, 7, 0.6, [0.0, 0.3], 0.3),  # single images mostly off the ball: its fits continued, mined; they score better
    (0.5, 7, 0.1, [0.0, 0.3], 0.0),  # continued, mined: they score worse; the first kept
    (0.5, 7, 0.4, [0.0, 0.3], 0.0),  # a tie (the shipped stage chosen in both): the first kept
    (0.5, 0, 0.9, [0.0], 0.0),  # off the ball, but its network has no false alarm to mine: not continued
    (0.1, 7, 0.9, [0.0], 0.0),  # single images mostly right: nothing to mine
])
def test_learned_mined_auto_trains_again_where_single_images_miss(synthetic_ball_coco, monkeypatch, first_outliers, alarms,
                                                                  mined_gain, expect_calls, expect_kept):
    """``--learned-mined auto`` (the default): where the chosen stage's single images are off the ball in more than
    ``MINE_WHEN_OUTLIERS`` of the cross-validation's images and its network has false alarms in the labelled frames,
    each fit of the stage is continued (the first call's networks, ``resume``) with them mined and the one the
    cross-validation scores better is written."""
    from types import SimpleNamespace

    import harness.experiments.detector.learned_train as L
    from harness.experiments.detector.train import MINE_WHEN_OUTLIERS, MINED_SHARE, SHIPPED_MODELS, TrainOptions, train

    assert MINE_WHEN_OUTLIERS == 0.2 and MINED_SHARE == 0.3  # the figures this table is written for
    import dataclasses

    white = BallSegmentationModel.load(SHIPPED_MODELS["white"]).learned  # a real stage stands for each training's
    stages = {0.0: white, MINED_SHARE: dataclasses.replace(white, description="mined")}
    calls, first_kw = [], []

    def fake_stage(labelled, images, folds, *, mined, **kw):
        calls.append(mined)
        if mined:  # the second call continues the first's networks, which the first was asked to keep
            assert kw["resume"] is first_kw[0]["states"] and isinstance(kw["resume"], dict)
        else:
            first_kw.append(kw)
        gain = 0.4 if mined == 0 else mined_gain
        chosen = SimpleNamespace(name="scratch", gain=gain, line=lambda: f"scratch: gain {gain}")
        single = SimpleNamespace(recall=0.5, outlier_rate=first_outliers if mined == 0 else 0.0)
        return stages[mined], dict(choices=[chosen], chosen=chosen, folds=len(folds), single=single, single_threshold=0.4, k=4)

    monkeypatch.setattr(L, "train_stage", fake_stage)
    monkeypatch.setattr(L, "false_alarms", lambda stage, images, labelled: alarms if stage is white else 0)

    labelled = read_coco(synthetic_ball_coco(12, 3))
    base = BallSegmentationModel.load(SHIPPED_MODELS["orange"])  # its filter kept: only the stage's choice runs
    model, info = train(labelled, TrainOptions(learned="on", filter="keep", allow_no_ball=True), progress=False, log=lambda m: None, base=base)
    assert calls == expect_calls
    assert info["learned"]["mined"] == expect_kept
    assert model.learned is stages[expect_kept]  # the stage written is the one kept
    trial = info["learned"].get("mining")
    assert (trial is None) == (first_outliers <= MINE_WHEN_OUTLIERS)
    if trial is not None:
        assert trial["false_alarms"] == alarms and trial["kept"] == (expect_kept > 0)
        assert (trial["with"] is None) == (alarms == 0) and trial["without"] == "scratch: gain 0.4"


def test_false_alarms_count_candidates_off_the_labelled_balls():
    """What a fit would mine: candidates of heat >= MINE_HEAT off every ball (farther than its diameter, and 8
    network pixels), the best MINE_PER_IMAGE of each image (asked of the stage)."""
    from harness.experiments.detector.coco import LabelledImage
    from harness.experiments.detector.learned_train import MINE_HEAT, MINE_PER_IMAGE, false_alarms

    asked = []

    class Stage:
        def scale_of(self, h, w):
            return 0.5  # 8 network pixels = 16 image pixels

        def candidates(self, image, window, k, threshold):
            asked.append((k, threshold))
            uv = np.array([[50.0, 50.0], [65.0, 50.0], [50.0, 70.0], [200.0, 10.0]])
            return uv, np.ones(len(uv)), np.full(len(uv), 10.0)

    image = np.zeros((120, 240, 3), np.uint8)
    ball = LabelledImage("a.png", 240, 120, np.array([[45.0, 45.0, 10.0, 10.0]]), np.array([[50.0, 50.0]]))
    empty = LabelledImage("b.png", 240, 120, np.zeros((0, 4)), np.zeros((0, 2)))
    # on the ball; 15 px away (< 16: the 8 network pixels); 20 px away; far: two false alarms, and four in the empty image
    assert false_alarms(Stage(), [image, image], [ball, empty]) == 2 + 4
    assert asked == [(MINE_PER_IMAGE, MINE_HEAT)] * 2


def test_a_second_call_continues_the_first_calls_networks_with_their_false_alarms_mined(synthetic_ball_coco, monkeypatch):
    """``train_stage(..., resume=states)``: every fit of the second call (each fold's and the file's) starts from the
    first call's network of the same choice and fold, runs ``continue_steps`` steps with the mined share, mining before
    its first step; the first call's own fits mine nothing. Where the second call writes another choice than the
    first, that choice's network is fitted on every image first, as the first call would have, then continued."""
    import harness.experiments.detector.learned_train as L
    from harness.experiments.detector.train import cv_folds

    labelled = read_coco(synthetic_ball_coco(9, 5))
    images = [load_image(li) for li in labelled]
    folds = cv_folds(labelled, 3)
    fits = []
    real_fit = L.fit_learned

    def recording_fit(items, opts, seed, *, state=None, **kw):
        out = real_fit(items, opts, seed, state=state, **kw)
        fits.append(dict(steps=opts.iterations, mined=opts.p_mined, first=opts.mine_first, start=state, out=out[0]))
        return out

    monkeypatch.setattr(L, "fit_learned", recording_fit)
    states: dict = {}
    kw = dict(base=None, seed=0, scratch_steps=8, finetune_steps=3, log=lambda m: None)
    L.train_stage(labelled, images, folds, states=states, **kw)
    first = list(fits)
    assert all(f["mined"] == 0 and f["start"] is None for f in first)  # from scratch, nothing mined
    assert sorted(states["folds"]) == [("scratch", f) for f in range(len(folds))]
    fits.clear()
    n = L.continue_steps(3, 8)
    _, info = L.train_stage(labelled, images, folds, mined=0.3, resume=states, **kw)
    for f, fit in enumerate(fits[:len(folds)]):  # the folds' fits: continued from the first call's network of that fold
        assert fit["steps"] == n and fit["mined"] == 0.3 and fit["first"]
        assert fit["start"] is states["folds"][("scratch", f)]
    (final,) = fits[len(folds):]  # the file's: the first call's network of the same choice (the only one: scratch), continued
    assert info["chosen"].name == states["final"][0] == "scratch"
    assert final["start"] is states["final"][1] and final["steps"] == n and final["mined"] == 0.3


# -- the cross-validation's fits on worker processes ---------------------------------------------------------------
def test_fits_on_worker_processes_give_the_same_networks_as_here(synthetic_ball_coco):
    """run_fits on two fresh worker processes: every fit's network is byte for byte the one this process trains
    (torch on one thread, each fit seeded by its task), whichever worker ran it and in whatever order they finished."""
    from harness.experiments.detector.learned_train import FitTask, run_fits

    labelled = read_coco(synthetic_ball_coco(8, 0))
    items = items_at_scale([(load_image(li), li) for li in labelled], 640)
    tasks = [FitTask(items, LearnedTrainOptions(iterations=n, batch=4, patch_px=64), seed, None)
             for n, seed in ((3, 1), (5, 2), (2, 3))]
    here = dict(run_fits(tasks, 1, keys="abc"))
    there = dict(run_fits(tasks, 2, keys="abc"))
    assert sorted(there) == ["a", "b", "c"]
    for key in "abc":
        assert there[key][1] == here[key][1]  # the ONNX bytes
        assert all(torch.equal(there[key][0][k], here[key][0][k]) for k in here[key][0])
    with pytest.raises(ValueError, match="2 keys for 3 tasks"):
        list(run_fits(tasks, 1, keys="ab"))


def test_workers_are_used_only_for_fits_long_enough_to_pay_for_them():
    from harness.experiments.detector.learned_train import MIN_PARALLEL_STEPS, FitTask, auto_workers

    import os

    from harness.experiments.detector.learned_train import WORKER_BASE_BYTES

    image = np.zeros((540, 960, 3), np.uint8)  # 1.56 MB

    def tasks(steps, n=6, images=10):
        return [FitTask([LearnedItem(image, np.zeros((0, 2)), np.zeros(0), 1.0, "x")] * images, LearnedTrainOptions(iterations=steps), 0, None)
                for _ in range(n)]

    assert auto_workers(tasks(10), None) == 1  # the tests' short fits: a worker's start would cost more than they take
    cpus = max(1, min(len(os.sched_getaffinity(0)), 6))
    assert auto_workers(tasks(MIN_PARALLEL_STEPS), None) == cpus
    assert auto_workers(tasks(MIN_PARALLEL_STEPS, n=1), None) == 1
    per_worker = WORKER_BASE_BYTES + 2 * 10 * image.nbytes
    assert auto_workers(tasks(MIN_PARALLEL_STEPS), 100 * per_worker) == cpus
    assert auto_workers(tasks(MIN_PARALLEL_STEPS), per_worker + 1) == 1  # the memory holds one worker: one
    assert auto_workers(tasks(MIN_PARALLEL_STEPS), 1000) == 1  # none: this process, never zero


def test_rt2_train_writes_the_same_model_with_one_worker_or_two(synthetic_ball_coco, tmp_path, capsys):
    """`rt2 train --workers 2` (the cross-validation's fits on two processes) and `--workers 1`: the same arrays."""
    data = str(synthetic_ball_coco(12, 4))
    files = {}
    for w in (1, 2):
        files[w] = tmp_path / f"m{w}.npz"
        assert main(["train", "--data", data, "--out", str(files[w]), "--epochs", "1", "--from", "none", "--learned", "on",
                     "--learned-steps", "12", "--learned-folds", "2", "--force", "--seed", "0", "--workers", str(w)]) == 0
    capsys.readouterr()
    a, b = np.load(files[1], allow_pickle=False), np.load(files[2], allow_pickle=False)
    assert sorted(a.files) == sorted(b.files) and "learned_onnx" in a.files
    for k in a.files:
        if "description" not in k:  # the descriptions name the command, whose --out and --workers differ
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_adams_multi_tensor_update_gives_the_one_tensor_loops_bytes():
    """fit_learned's Adam runs `foreach` (faster); its arithmetic per element is the loop's: the same weights."""
    import math

    from harness.experiments.detector.learned_train import _loss, build_net

    def run(foreach, steps=12):
        torch.manual_seed(0)
        net = build_net(torch)
        opt = torch.optim.Adam(net.parameters(), lr=3e-3, weight_decay=1e-5, foreach=foreach)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda i: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * i / steps)))
        rng = np.random.default_rng(0)
        for _ in range(steps):
            out = net(torch.from_numpy(rng.integers(0, 255, (4, 64, 64, 3), dtype=np.uint8)))
            g = out.shape[-1]
            heat, off, logd = (torch.from_numpy(rng.random(s, dtype=np.float32)) for s in ((4, g, g), (4, 2, g, g), (4, g, g)))
            mask = torch.from_numpy((rng.random((4, g, g)) < 0.02).astype(np.float32))
            opt.zero_grad()
            _loss(torch, out, heat, off, logd, mask).backward()
            opt.step()
            sched.step()
        return net.state_dict()

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        a, b = run(False), run(True)
    finally:
        torch.set_num_threads(threads)
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="reads the children from /proc")
def test_ctrl_c_stops_rt2_train_and_its_worker_processes(synthetic_ball_coco, tmp_path):
    """SIGINT while the fits run on two workers: exit 130 at once, no worker left, no model written."""
    import os

    from tests.stop_times import descendants, wait_gone
    import select
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "m.npz"
    proc = subprocess.Popen([sys.executable, "-m", "harness.cli", "train", "--data", str(synthetic_ball_coco(12, 5)), "--out", str(out),
                             "--epochs", "1", "--from", "none", "--learned", "on", "--learned-steps", "20000", "--learned-folds", "2",
                             "--force", "--workers", "2"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        seen, t_end = "", time.monotonic() + 300
        while "cross-validation folds" not in seen and time.monotonic() < t_end and proc.poll() is None:
            if select.select([proc.stdout], [], [], 1.0)[0]:
                seen += proc.stdout.readline()
        assert "cross-validation folds" in seen, seen
        kids = []
        while len(kids) < 2 and time.monotonic() < t_end:  # the two workers (and multiprocessing's helper, if any)
            kids = descendants(proc.pid)
            time.sleep(0.2)
        assert len(kids) >= 2, kids
        time.sleep(2.0)  # the workers are training
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 130
        assert time.monotonic() - t0 < 15  # not a fit's end
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert not wait_gone(kids, 5.0), "worker processes still run after rt2 train stopped"
    assert not out.exists()


def test_a_tie_keeps_the_bases_own_threshold_where_it_is_among_the_best():
    """Every threshold up to 0.6 finds the one ball and nothing else: the higher wins a tie, unless the base's own
    operating point (``prefer``) is among the best; a preferred threshold that scores worse is not taken."""
    from harness.experiments.detector.learned_train import _best_threshold, single_image_threshold

    truth = ([np.array([[10.0, 10.0]])], [np.array([10.0])])
    cands = [(np.array([[10.0, 10.0]]), np.array([0.65]))]
    assert _best_threshold(truth, cands, 4, 6.0)[0] == 0.6
    assert _best_threshold(truth, cands, 4, 6.0, prefer=0.5)[0] == 0.5
    assert _best_threshold(truth, cands, 4, 6.0, prefer=0.8)[0] == 0.6
    assert single_image_threshold(truth, cands, 0.6, 6.0, prefer=0.4)[0] == 0.4


def test_the_bases_own_threshold_is_kept_unless_another_wins_by_more_than_one_labelled_ball():
    """Four balls, one a candidate at 0.45: 0.4 finds it too and beats 0.5 by one ball (a quarter) and nothing else;
    the base's own 0.5 is kept with a margin of one ball, not with less."""
    from harness.experiments.detector.learned_train import _best_threshold, one_ball, single_image_threshold

    truth = ([np.array([[10.0, 10.0]]), np.array([[10.0, 10.0]]), np.array([[10.0, 10.0]]), np.array([[10.0, 10.0]])], [np.array([10.0])] * 4)
    cands = [(np.array([[10.0, 10.0]]), np.array([s])) for s in (0.9, 0.9, 0.9, 0.45)]
    assert one_ball(truth) == 0.25 and one_ball(([np.zeros((0, 2))], [np.zeros(0)])) == 0.0
    assert _best_threshold(truth, cands, 4, 6.0, prefer=0.5)[0] == 0.4  # a tie only: the better one wins
    assert _best_threshold(truth, cands, 4, 6.0, prefer=0.5, margin=0.25)[0] == 0.5
    assert _best_threshold(truth, cands, 4, 6.0, prefer=0.5, margin=0.2)[0] == 0.4
    assert single_image_threshold(truth, cands, 0.6, 6.0, prefer=0.5, margin=0.25)[0] == 0.5
    assert single_image_threshold(truth, cands, 0.6, 6.0, prefer=0.5)[0] == 0.4


@pytest.mark.parametrize("lead, chosen", [(0.0, "shipped"), (0.04, "shipped"), (0.1, "shipped"), (0.11, "fine-tuned")])
def test_the_shipped_stage_is_kept_unless_another_wins_by_more_than_one_labelled_ball(synthetic_ball_coco, monkeypatch, lead, chosen):
    """On few labels the folds decide a ball or two by chance: a fine-tune (or a stage from scratch) replaces the
    shipped stage only when it scores more than one labelled ball's share better (10 balls: 0.1)."""
    from harness.experiments.detector import learned_train as L
    from harness.experiments.detector.train import cv_folds
    from tracker.detection.learned import LearnedStage

    labelled, images, onnx = _twelve_images_and_a_network(synthetic_ball_coco)
    assert sum(li.n_balls for li in labelled) == 10
    base = LearnedStage(onnx, max_side_px=128, threshold=0.5)
    monkeypatch.setattr(L.StageChoice, "gain", property(lambda c: {"shipped": 0.5, "fine-tuned": 0.5 + lead}.get(c.name, 0.0)))
    lines = []
    stage, info = L.train_stage(labelled, images, cv_folds(labelled, 2), base=base, seed=0, finetune_steps=3, scratch_steps=3, batch=4,
                                patch_px=32, log=lines.append)
    assert info["chosen"].name == chosen
    kept = [line for line in lines if line.startswith("learned stage: the shipped stage kept: fine-tuned scores")]
    assert len(kept) == (1 if 0 < lead <= 0.1 else 0)
    if chosen == "shipped":
        assert stage.onnx == base.onnx
