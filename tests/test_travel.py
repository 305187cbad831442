"""A run folder that travels (flatlandia.plumbing.travel): a finished run copied into another clone of
the same commit, with or without its times, plans nothing; a copy whose content changed reruns the
jobs that changed, and the run's start says so in one line.

Slow lane: it runs the tiny scene's `maps` for real (seconds) in a clone of the checkout, and the
Lund photos' (about 80 s: folder outputs, masks and the SfM model).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from checkout_copy import git, tagged_repository
from conftest import TINY_SCENE
from snakemake_runner import job_stats, smk

pytestmark = pytest.mark.slow

RUN = ("results", "logs", ".snakemake/metadata", ".snakemake/flatlandia_home.json")
ARGS = ("maps", "--configfile", "config/test/tiny.yaml")


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A clone of the checkout (one clean commit) with the tiny scene's maps built in it."""
    first = tagged_repository(tmp_path_factory.mktemp("travel") / "first")
    res = smk(first, first, "--cores", "2", *ARGS)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert (first / ".snakemake/flatlandia_home.json").is_file()
    return first


def _second_clone_with_the_run(first: Path, dest: Path, keep_times: bool) -> Path:
    """``git clone`` of the first clone (checked out now: its files newer than the run), then the run
    folder copied in (``cp -a`` or ``cp -r``)."""
    git(dest.parent, "clone", "-q", str(first), str(dest))
    copy = shutil.copy2 if keep_times else shutil.copy
    for name in RUN:
        src = first / name
        if src.is_dir():
            shutil.copytree(src, dest / name, copy_function=copy, symlinks=True)
        else:
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            copy(src, dest / name)
    return dest


@pytest.mark.parametrize("keep_times", [True, False], ids=["cp -a", "cp -r"])
def test_a_finished_run_copied_into_another_clone_plans_nothing(finished, tmp_path, keep_times):
    second = _second_clone_with_the_run(finished, tmp_path / "second", keep_times)
    res = smk(second, second, "-n", *ARGS)
    assert res.returncode == 0, res.stderr[-3000:]
    said = [ln for ln in res.stderr.splitlines() if "this run folder was last run from" in ln]
    assert len(said) == 1 and str(finished) in said[0] and "not re-timed: none" in said[0], res.stderr[-3000:]
    assert "Nothing to be done" in res.stdout + res.stderr, res.stdout[-3000:]
    again = smk(second, second, "-n", *ARGS)  # settled once: the next plan says nothing of it
    assert "last run from" not in again.stderr and "Nothing to be done" in again.stdout + again.stderr


def test_a_copy_whose_content_changed_reruns_what_changed(finished, tmp_path):
    second = _second_clone_with_the_run(finished, tmp_path / "second", keep_times=True)
    ref = second / f"results/{TINY_SCENE}/maps/reference_map.geojson"
    ref.write_text(ref.read_text().replace("FeatureCollection", "FeatureCollection", 1) + "\n")
    res = smk(second, second, "-n", *ARGS)
    said = [ln for ln in res.stderr.splitlines() if "this run folder was last run from" in ln]
    assert len(said) == 1 and "1 an output differs from what was built" in said[0], res.stderr[-3000:]
    stats = job_stats(res.stdout)
    assert stats.get("reference_map") == 1 and stats["total"] >= 1, stats


def test_a_copy_into_a_clone_of_other_code_reruns(finished, tmp_path):
    second = _second_clone_with_the_run(finished, tmp_path / "second", keep_times=True)
    script = second / "workflow/scripts/reference_map.py"
    script.write_text(script.read_text() + "\n# another version of the code\n")
    git(second, "-c", "user.name=t", "-c", "user.email=t@example.org", "commit", "-qam", "other code")
    res = smk(second, second, "-n", *ARGS)
    said = [ln for ln in res.stderr.splitlines() if "this run folder was last run from" in ln]
    assert len(said) == 1 and "built by other code" in said[0], res.stderr[-3000:]
    assert job_stats(res.stdout)["total"] > 0


@pytest.fixture(scope="module")
def finished_lund(tmp_path_factory, flat_root, lund) -> tuple[Path, tuple[str, ...]]:
    """A clone of the checkout with the Lund photos' maps built in it (rules with folder outputs)."""
    import pandas as pd

    first = tagged_repository(tmp_path_factory.mktemp("travel_lund") / "first")
    sheet = pd.read_csv(first / "config/scenes.tsv", sep="\t", dtype=str, keep_default_na=False)
    sheet.loc[sheet["scene"] == "lund", "path"] = str(lund)
    sheet.to_csv(first / "results_sheet.tsv", sep="\t", index=False)
    args = (
        "maps",
        "--config",
        "select=[lund]",
        f"flatlandia_root={flat_root}",
        f"scenes={first / 'results_sheet.tsv'}",
    )
    res = smk(first, first, "--cores", "2", *args)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return first, args


def test_a_run_with_folder_outputs_copied_into_another_clone_plans_nothing(finished_lund, tmp_path):
    """The masks and the SfM model are folder outputs; each job's benchmark file is re-timed after the
    outputs (Snakemake weighs a job's oldest output or benchmark file against its inputs: an old
    benchmark file planned SfM and the 11 jobs after it again)."""
    first, args = finished_lund
    second = _second_clone_with_the_run(first, tmp_path / "second", keep_times=True)
    res = smk(second, second, "-n", *args)
    said = [ln for ln in res.stderr.splitlines() if "this run folder was last run from" in ln]
    assert len(said) == 1 and "not re-timed: none" in said[0], res.stderr[-3000:]
    assert "Nothing to be done" in res.stdout + res.stderr, res.stdout[-3000:]
