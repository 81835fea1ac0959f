"""Held-out scoring: seeds per family from streams never tuned on, exact scores against the
runner, policies beside static parameters, and the ``crowdsim heldout`` command."""

from __future__ import annotations

import json

import numpy as np
import pytest

from crowdsim.cli import main
from envs.heldout import evaluate_heldout, heldout_count, heldout_episodes, heldout_table
from envs.param_space import ParamSpace
from envs.tuners import Objective
from synth_data.suites import suite_specs
from tracker.runner import run_tracker

TINY = {
    "scenarios": ["counterflow", "crossing"],
    "agents": [6, 8],
    "frames": 10,
    "warmup_steps": 4,
    "template_px": [10],
    "max_width": 160,
    "max_height": 120,
}


def objective(**kw):
    return Objective(scenarios=dict(TINY), train_episodes=2, **kw)


class ConstantPolicy:
    """A stand-in for a stable-baselines3 model: always the same action."""

    def __init__(self, action):
        self.action = np.asarray(action, np.float32)

    def predict(self, obs, deterministic=True):
        return self.action, None


def policy(action, k_frames=4):
    return ConstantPolicy(action), {"algo": "ppo", "env_kwargs": {"k_frames": k_frames}}


def test_scenario_families_get_their_seeds_from_a_stream_never_tuned_on():
    obj = objective()
    skipped = []
    drawn = list(heldout_episodes(obj, 3, skipped))
    fams = [f for f, _, _ in drawn]
    assert sorted(fams) == ["counterflow"] * 3 + ["crossing"] * 3
    assert all(len(seq.gt_points()[0]) > 0 for _, seq, _ in drawn)
    assert skipped  # 6-8 people crossing a small frame: some episodes see nobody
    specs = [spec for _, _, spec in drawn]
    assert all(s.scenario["name"] == f for s, f in zip(specs, fams, strict=True))
    tuning = obj.episodes()
    tuned_seeds = {tuning.spec(i).seed for i in range(200)}
    assert not tuned_seeds & {s.seed for s in specs}
    assert len({s.seed for s in specs}) == 6
    again = [(f, spec) for f, _, spec in heldout_episodes(obj, 3)]
    assert again == list(zip(fams, specs, strict=True))  # deterministic


def test_builtin_suite_sequences_are_reseeded_per_held_out_seed():
    obj = Objective(suite="ucf9", only=("seq8", "seq2"), frames=3)
    assert heldout_count(obj, 2) == 4
    drawn = [(f, spec) for f, _, spec in heldout_episodes(obj, 2)]
    orig = {s.name: s.seed for s in suite_specs("ucf9", ["seq2", "seq8"])}
    assert sorted(f for f, _ in drawn) == ["seq2", "seq2", "seq8", "seq8"]
    for fam, spec in drawn:
        assert spec.name == fam and spec.frames == 3
        assert spec.seed - orig[fam] in (1, 2)  # tuning uses offset 0
    assert len({(f, s.seed) for f, s in drawn}) == 4


def test_a_folder_of_spec_files_is_reseeded_like_a_builtin_suite(tmp_path):
    """A suite folder of specs (``calibrate --out`` writes one) renders in memory and is
    re-seeded for held-out scoring, as its built-in twin is; a folder of MOT sequences is not."""
    import shutil

    from synth_data.suites import is_spec_suite, suite_files

    for f in suite_files("ucf9"):
        shutil.copy(f, tmp_path / f.name)
    assert is_spec_suite(tmp_path) and is_spec_suite(str(tmp_path))
    mine = Objective(suite=str(tmp_path), only=("seq8", "seq2"), frames=3)
    builtin = Objective(suite="ucf9", only=("seq8", "seq2"), frames=3)
    assert heldout_count(mine, 2) == heldout_count(builtin, 2) == 4
    assert [spec.seed for _, _, spec in heldout_episodes(mine, 2)] == [
        spec.seed for _, _, spec in heldout_episodes(builtin, 2)
    ]
    train = mine.episodes()
    assert not train.on_disk and len(train) == 2
    (tmp_path / "seqinfo.ini").write_text("[Sequence]\n")  # now a MOT sequence folder
    assert not is_spec_suite(tmp_path)


def test_scores_equal_the_runner_and_a_default_action_policy_equals_the_defaults():
    obj = objective()
    base = obj.space().base
    space = ParamSpace(base=base)
    other = space.to_params(np.array([0.8, -0.8, 0.5, -0.5, 0.9]))
    res = evaluate_heldout(
        obj,
        {"defaults": base, "other": other},
        2,
        policies={"zero": policy(np.zeros(5)), "far": policy([0.8, -0.8, 0.5, -0.5, 0.9], 100)},
        metrics="accuracy",
    )
    assert res["labels"] == ["defaults", "other", "zero", "far"]
    assert len(res["sequences"]) == 4 and res["seeds_per_family"] == 2
    for (fam, seq, spec), row in zip(heldout_episodes(obj, 2), res["sequences"], strict=True):
        assert row["family"] == fam and row["seed"] == spec.seed
        direct = run_tracker("bqp", seq, params=base, metrics="accuracy").report
        assert row["defaults"]["acc@5"] == direct["acc@5"]
        assert row["zero"] == row["defaults"]  # action 0 is the paper defaults
        # a policy acting once per 100 frames sets its parameters before frame 1: as static
        assert row["far"] == row["other"]
    assert any(r["other"] != r["defaults"] for r in res["sequences"])
    for fam, block in res["families"].items():
        vals = [r["other"]["acc@15"] for r in res["sequences"] if r["family"] == fam]
        assert block["other"]["acc@15"] == {
            "mean": pytest.approx(np.mean(vals)),
            "std": pytest.approx(np.std(vals)),
            "n": 2,
        }
    d = [r["other"]["acc@5"] - r["defaults"]["acc@5"] for r in res["sequences"]]
    assert res["reference"] == "defaults" and set(res["paired"]) == {"other", "zero", "far"}
    assert res["paired"]["other"]["acc@5"] == {
        "mean": pytest.approx(np.mean(d)),
        "std": pytest.approx(np.std(d)),
        "better": sum(x > 0 for x in d),
        "worse": sum(x < 0 for x in d),
        "n": 4,
    }
    assert res["paired"]["zero"]["acc@5"]["mean"] == 0.0
    table = heldout_table(res)
    # header, rule, (2 families + all) x 4 labels, 3 paired rows
    assert table.count("\n") == 2 + 3 * 4 + 3
    assert "| all | 4 | far |" in table and "| paired | 4 | zero − defaults | +0.0 ± 0.0" in table


def test_heldout_command_scores_a_params_file_and_refuses_bad_input(tmp_path, capsys):
    params = tmp_path / "best_params.json"
    params.write_text(json.dumps({"tracker": "bqp", "params": {"zeta": 0.5, "eta": 0.1}}))
    scen = tmp_path / "dist.json"
    scen.write_text(json.dumps(TINY))
    out = tmp_path / "h"
    base = ["heldout", "--scenarios", str(scen), "--seeds", "1", "--no-progress"]
    argv = [*base, "--params", f"mine={params}", "--metrics", "accuracy", "--out", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "2 held-out sequences (1 per family)" in printed and "| all | 2 | mine |" in printed
    doc = json.loads((out / "heldout.json").read_text())
    assert doc["labels"] == ["defaults", "mine"] and set(doc["families"]) == {
        "counterflow",
        "crossing",
    }
    assert (out / "heldout.png").stat().st_size > 0 and (out / "heldout.md").is_file()
    assert main(argv) == 0  # its own result is replaced

    def refused(extra, needle):
        assert main([*base, *extra]) == 2
        err = capsys.readouterr().err
        assert needle in err and "Traceback" not in err, err

    refused(["--no-defaults", "--out", str(out)], "nothing to score")
    refused(["--seeds", "0", "--out", str(out)], "--seeds must be >= 1, got 0")
    refused(["--params", "a=", "--out", str(out)], "expected [LABEL=]FILE, got 'a='")
    refused(["--params", f"x={params}", f"x={params}", "--out", str(out)], "label 'x' given twice")
    refused(
        ["--params", str(params), "--policy", "tuned=m.zip", "--out", str(out)], "is a --params"
    )
    refused(["--params", f"defaults={params}", "--out", str(out)], "names the paper defaults' row")
    ncc = tmp_path / "ncc.json"
    ncc.write_text(json.dumps({"tracker": "ncc", "params": {}}))
    refused(["--params", str(ncc), "--out", str(out)], "parameters of the 'ncc' tracker")
    refused(["--policy", str(tmp_path / "none.zip"), "--out", str(out)], "none.zip")
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "heldout.json").write_text('{"my": "notes"}')
    refused(["--out", str(theirs)], "heldout.json exists and was not written by crowdsim heldout")
    assert (theirs / "heldout.json").read_text() == '{"my": "notes"}'


def test_heldout_never_replaces_a_users_table_or_plot(tmp_path, capsys):
    """Only files crowdsim heldout can prove it wrote (their SHA-256 in its heldout.json)
    are replaced: a user's own heldout.md or heldout.png, beside our heldout.json or alone,
    is refused before any work and left as it was."""
    scen = tmp_path / "dist.json"
    scen.write_text(json.dumps({**TINY, "scenarios": ["counterflow"]}))
    argv = ["heldout", "--scenarios", str(scen), "--seeds", "1", "--no-progress"]
    argv += ["--metrics", "accuracy"]
    out = tmp_path / "h"
    assert main([*argv, "--out", str(out)]) == 0
    doc = json.loads((out / "heldout.json").read_text())
    assert set(doc["files"]) == {"heldout.md", "heldout.png"}
    assert main([*argv, "--out", str(out)]) == 0  # ours: replaced
    capsys.readouterr()
    for name, mine in (("heldout.md", b"my notes\n"), ("heldout.png", b"\x89PNG my plot")):
        (out / name).write_bytes(mine)
        assert main([*argv, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert f"{out / name} exists and was not written by crowdsim heldout" in err, err
        assert (out / name).read_bytes() == mine
        (out / name).unlink()
        alone = tmp_path / f"alone-{name}"
        alone.mkdir()
        (alone / name).write_bytes(mine)
        assert main([*argv, "--out", str(alone)]) == 2
        assert "not written by crowdsim heldout" in capsys.readouterr().err
        assert sorted(p.name for p in alone.iterdir()) == [name]


def test_outputs_stay_provable_when_a_run_dies_between_record_and_renames(tmp_path, monkeypatch):
    """write_outputs writes the record (new and previous digests) before renaming the new
    files into place: a run killed in between leaves the old files provably ours."""
    import os

    import crowdsim.atomic
    from envs.outputs import check_outputs, write_outputs

    def ours(doc):
        return doc.get("kind") == "t"

    write_outputs(tmp_path, "r.json", {"kind": "t"}, {"a.md": lambda p: p.write_text("one\n")})
    real = os.replace

    def killed_before_a_md(src, dst):
        if os.fspath(dst).endswith("a.md"):
            raise KeyboardInterrupt  # the record is written, a.md not yet renamed
        real(src, dst)

    monkeypatch.setattr(crowdsim.atomic.os, "replace", killed_before_a_md)
    with pytest.raises(KeyboardInterrupt):
        write_outputs(tmp_path, "r.json", {"kind": "t"}, {"a.md": lambda p: p.write_text("2\n")})
    monkeypatch.setattr(crowdsim.atomic.os, "replace", real)
    assert (tmp_path / "a.md").read_text() == "one\n"
    assert json.loads((tmp_path / "r.json").read_text())["previous_files"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.md", "r.json"]  # no temp left
    check_outputs(tmp_path, "r.json", ("a.md",), ours, "t")  # still ours
    (tmp_path / "a.md").write_text("mine\n")
    with pytest.raises(ValueError, match="a.md exists and was not written by t"):
        check_outputs(tmp_path, "r.json", ("a.md",), ours, "t")


@pytest.mark.parametrize(
    "damage", [{"previous_files": "x"}, {"files": 3}, {"files": {"a.md": [1]}}]
)
def test_a_damaged_record_is_refused_by_name_not_a_traceback(tmp_path, damage):
    """A record whose digests are not a table of names (damaged, or edited by hand) proves
    nothing: one ValueError naming it (it had been an AttributeError or TypeError)."""
    from envs.outputs import check_outputs, write_outputs

    def ours(doc):
        return doc.get("kind") == "t"

    write_outputs(tmp_path, "r.json", {"kind": "t"}, {"a.md": lambda p: p.write_text("one\n")})
    doc = json.loads((tmp_path / "r.json").read_text())
    (tmp_path / "r.json").write_text(json.dumps({**doc, **damage}))
    with pytest.raises(ValueError, match=r"(r\.json|a\.md) exists and was not written by t"):
        check_outputs(tmp_path, "r.json", ("a.md",), ours, "t")
    assert (tmp_path / "a.md").read_text() == "one\n"


def test_heldout_plot_shows_both_thresholds_and_its_title_fits(tmp_path, monkeypatch):
    """One panel per threshold the record holds (acc@5 alone was drawn before, whatever the
    table said), and with one family (and "all") the title fits the figure (a one-line
    title ran past both edges of the narrowest PNG)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    import crowdsim.plotting as plotting
    from envs.heldout import plot_heldout

    def cell(mean):
        return {"mean": mean, "std": 0.0, "n": 1}

    block = {
        label: {"acc@5": cell(60.0 + i), "acc@15": cell(90.0 + i), "hota": cell(50.0)}
        for i, label in enumerate(("defaults", "tuned"))
    }
    result = {
        "labels": ["defaults", "tuned"],
        "families": {"seq8": block},
        "summary": block,
        "seeds_per_family": 1,
    }
    figs = []
    real = plotting.save_figure
    monkeypatch.setattr(
        plotting, "save_figure", lambda fig, path, dpi=120: figs.append(fig) or real(fig, path, dpi)
    )
    plot_heldout(result, tmp_path / "heldout.png")
    fig = figs[0]
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.tight_layout()
    box = fig._suptitle.get_window_extent(renderer)
    assert 0 <= box.x0 and box.x1 <= fig.bbox.width
    assert "1 seed per family" in fig._suptitle.get_text()
    assert [ax.get_ylabel() for ax in fig.axes] == ["acc@5 (%)", "acc@15 (%)"]
    heights = [[round(b.get_height(), 1) for b in ax.patches] for ax in fig.axes]
    assert heights == [[60.0, 60.0, 61.0, 61.0], [90.0, 90.0, 91.0, 91.0]]
    legend = fig.axes[-1].get_legend()
    assert [t.get_text() for t in legend.get_texts()] == ["defaults", "tuned"]
