"""What a new user trips over, found by following README.md from a fresh clone: each ends in a
result or one clear ERROR/WARNING line, never a traceback or a silent success."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import REPO, TINY_ROOT, smk_dry_run

from flatlandia import cli
from flatlandia.data import ingest

TINY = REPO / "config" / "test" / "tiny.yaml"
SHEET_HEAD = "scene\tsource\tcity\tname\tpath\turl\tsubfolder\n"


def _plan_with_sheet(tmp_path: Path, row: str):
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(SHEET_HEAD + row + "\n")
    return smk_dry_run(REPO, tmp_path, "maps", "--configfile", str(TINY), "--config", f"scenes={sheet}")


def _one_error(res) -> str:
    assert res.returncode != 0 and "Traceback" not in res.stderr + res.stdout, (res.stdout + res.stderr)[-3000:]
    errors = [ln for ln in (res.stdout + res.stderr).splitlines() if ln.startswith("ERROR:")]
    assert len(errors) == 1, (res.stdout + res.stderr)[-3000:]
    return errors[0]


def test_an_images_scene_whose_folder_is_missing_is_one_error_line_before_any_job(tmp_path):
    """A typo in the sheet's path column: was Snakemake's InputFunctionException with a traceback."""
    line = _one_error(_plan_with_sheet(tmp_path, f"mine\timages\tLund\tmy_walk\t{tmp_path / 'my_wlak'}\t\t"))
    assert "images scene mine" in line and "my_wlak' does not exist" in line and "no url" in line
    line = _one_error(_plan_with_sheet(tmp_path, "mine\timages\tLund\tmy_walk\t\t\t"))
    assert "images scene mine: its path is empty" in line


def test_an_images_scene_whose_path_is_a_photo_is_one_error_line(tmp_path):
    photo = tmp_path / "01.jpg"
    photo.write_bytes(b"\xff\xd8\xff")
    line = _one_error(_plan_with_sheet(tmp_path, f"mine\timages\tLund\tmy_walk\t{photo}\t\t"))
    assert f"its path '{photo}' is a file, not a folder" in line


def test_a_sheet_row_written_with_spaces_is_one_error_saying_tabs(tmp_path):
    """An editor that turns tabs into spaces: was a schema dump about the scene id's pattern."""
    line = _one_error(_plan_with_sheet(tmp_path, "mine    images  Lund    my_walk /data/my_walk"))
    assert line.endswith(
        "line 2: 'mine    images  Lund    my_walk /data/my_walk' is one column: the sheet's "
        "columns are separated by tabs, not spaces"
    )
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text("scene source city\n0 flatlandia Tinytown\n")
    res = smk_dry_run(REPO, tmp_path, "maps", "--configfile", str(TINY), "--config", f"scenes={sheet}")
    assert "line 1: 'scene source city' is one column: the sheet's columns are separated by tabs" in _one_error(res)


def test_an_images_scene_with_its_folder_still_plans(tmp_path):
    (tmp_path / "photos").mkdir()
    res = _plan_with_sheet(tmp_path, f"mine\timages\tLund\tmy_walk\t{tmp_path / 'photos'}\t\t")
    assert res.returncode == 0 and "image_audit" in res.stdout, res.stderr[-3000:]


# ---------------------------------------------------------------- align per scene (issue 45)

ALIGN_HEAD = "scene\tsource\tcity\tname\tpath\turl\tsubfolder\talign\n"
TINY_ROW = "0\tflatlandia\tFlatland\tFlatland_Synthetic_Street_0\t\t\t\t\n"


def _align_sheet(tmp_path: Path, *rows: str) -> Path:
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(ALIGN_HEAD + TINY_ROW + "".join(r + "\n" for r in rows))
    return sheet


def test_a_bad_align_cell_is_one_error_naming_the_sheet_line_and_value(tmp_path):
    (tmp_path / "photos").mkdir()
    for cell, said in [
        ("GPS", "line 3, column align: 'GPS' is not gps, none or empty (empty: the config's images.align.mode)"),
        ("local", "line 3, column align: 'local' is not gps, none or empty"),
    ]:
        sheet = _align_sheet(tmp_path, f"mine\timages\tLund\tmy_walk\t{tmp_path / 'photos'}\t\t\t{cell}")
        res = smk_dry_run(REPO, tmp_path, "maps", "--configfile", str(TINY), "--config", f"scenes={sheet}")
        assert _one_error(res).startswith(f"ERROR: {sheet}: {said}")
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(ALIGN_HEAD + TINY_ROW.replace("\t\n", "\tnone\n"))
    res = smk_dry_run(REPO, tmp_path, "maps", "--configfile", str(TINY), "--config", f"scenes={sheet}")
    assert _one_error(res) == (
        f"ERROR: {sheet}: line 2, column align: 'none' on published scene '0': only an images scene is aligned "
        "(leave the cell empty)"
    )


def test_the_sheet_sets_align_per_scene(tmp_path):
    """Scenes with and without GPS in one run (they needed a run each: images.align.mode is global): a
    scene's align cell is its mode, an empty cell the config's; the rules that read the mode get the
    scene's, and only the GPS-aligned scene is localized by the benchmark's methods."""
    from flatlandia.plumbing import debug, provenance

    for name in ("walk", "indoors"):
        (tmp_path / name).mkdir()
    sheet = _align_sheet(
        tmp_path,
        f"walk\timages\tLund\twalk\t{tmp_path / 'walk'}\t\t\t",
        f"indoors\timages\tLund\tindoors\t{tmp_path / 'indoors'}\t\t\tnone",
    )

    def settings(rule, scene, **config):
        job = debug.mock_snakemake(rule, tmp_path, [TINY], {"scenes": str(sheet), **config}, scene=scene)
        return provenance.rule_settings(job)

    assert settings("gps_alignment", "walk")["images.align"]["mode"] == "gps"
    indoors = settings("gps_alignment", "indoors")
    assert indoors["images.align"]["mode"] == "none" and indoors["images.align"]["unit_m"] == 1.0
    assert settings("image_audit", "indoors")["images.align.mode"] == "none"
    assert settings("image_audit", "walk", images={"align": {"mode": "none"}})["images.align.mode"] == "none"
    res = smk_dry_run(REPO, tmp_path, "benchmark", "--configfile", str(TINY), "--config", f"scenes={sheet}")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "results/walk/localization/localization.parquet" in res.stdout
    assert "results/indoors/localization" not in res.stdout


@pytest.mark.slow  # runs a Snakemake job (the audit of an empty folder, which fails at once)
def test_the_run_says_before_sfm_that_its_segmentation_labels_no_object(tmp_path):
    """The run's start, before its first job, says in one line that the default segmentation labels no
    object class (an empty map after minutes of SfM); a dry run plans silently."""
    from snakemake_runner import smk

    (tmp_path / "photos").mkdir()
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(SHEET_HEAD + f"mine\timages\tLund\tmy_walk\t{tmp_path / 'photos'}\t\t\n")
    args = ("results/mine/images/images.parquet", "--configfile", str(TINY), "--config", f"scenes={sheet}")
    res = smk(REPO, tmp_path, "--cores", "1", *args)
    out = res.stdout + res.stderr
    said = [ln for ln in out.splitlines() if "labels no object classes" in ln]
    assert said == [
        "flatlandia: WARNING: segment.backend offline labels no object classes: images scene(s) mine will get SfM "
        "and masks but an empty map (0 objects, 0 queries); for objects give per-pixel Vistas labels "
        "(segment.backend precomputed or transformers): docs/backends.md"
    ], out[-3000:]
    assert out.index(said[0]) < out.index("rule image_audit:")
    assert "labels no object classes" not in (smk_dry_run(REPO, tmp_path, *args).stderr)


def test_a_broken_optional_published_file_is_said_a_missing_one_is_not(tmp_path):
    """A truncated tokens.txt let the run end with status 0 and a PROBLEM line only in the rule's log."""
    root = tmp_path / "flat"
    shutil.copytree(TINY_ROOT, root)
    assert ingest.optional_problems(ingest.ingest_scene(root, "0")) == []
    tokens = root / "maps/0/tokens.txt"
    tokens.write_bytes(tokens.read_bytes()[:-5])
    (line,) = ingest.optional_problems(ingest.ingest_scene(root, "0"))
    assert line.startswith(f"{tokens}: size ") and "truncated" in line and "scene 0" in line
    tokens.unlink()  # absent: the published data's normal state for some scenes
    assert ingest.optional_problems(ingest.ingest_scene(root, "0")) == []


def _one_record(run: Path) -> Path:
    """A run folder holding one artifact and its provenance record, as a rule script leaves them."""
    artifact = run / "results/0/maps/reference_map.parquet"
    artifact.parent.mkdir(parents=True)
    artifact.write_bytes(b"map")
    from flatlandia.plumbing import provenance

    digest, size = provenance.path_digest(artifact)
    rec = {
        "rule": "reference_map",
        "wildcards": {"scene": "0"},
        "inputs": {},
        "outputs": {"results/0/maps/reference_map.parquet": {"sha256": digest, "bytes": size}},
        "config_hash": "0" * 16,
        "package_version": "0.1.0",
        "git_commit": "abc",
        "finished_at": "2026-11-28T00:00:00+00:00",
    }
    (run / "logs/provenance/reference_map").mkdir(parents=True)
    (run / "logs/provenance/reference_map/scene-0.json").write_text(json.dumps(rec))
    return artifact


def test_audit_takes_an_artifact_by_its_absolute_path(tmp_path, monkeypatch, capsys):
    """`flatlandia audit /full/path/results/...` in the run's folder said "no audit record"."""
    artifact = _one_record(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["audit", str(artifact)]) == 0
    assert "artifact: results/0/maps/reference_map.parquet" in capsys.readouterr().out


def test_audit_outside_the_run_folder_says_where_it_looked(tmp_path, monkeypatch, capsys):
    artifact = _one_record(tmp_path / "run")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert cli.main(["audit", str(artifact)]) == 1
    out = capsys.readouterr().err
    assert out.startswith(f"ERROR: no audit records in {tmp_path / 'elsewhere'}: run flatlandia audit in the run's")


def test_an_external_method_whose_poses_file_is_missing_is_one_error_line(tmp_path):
    """A misspelt `external[].poses`: the method was left out of every table, the run status 0."""
    import yaml

    cfg = tmp_path / "my.yaml"
    cfg.write_text(yaml.safe_dump({"external": [{"name": "poor", "poses": "poor_poses.cvs"}]}))
    res = smk_dry_run(REPO, tmp_path, "all", "--configfile", str(TINY), str(cfg))
    line = _one_error(res)
    assert line.startswith("ERROR: config: 'external.0.poses': 'poor_poses.cvs' is not a file") and "'poor'" in line
    (tmp_path / "poor_poses.cvs").write_text("scene,token,x_m,y_m,theta_deg\n")
    res = smk_dry_run(REPO, tmp_path, "all", "--configfile", str(TINY), str(cfg))
    assert res.returncode == 0 and "external_eval" in res.stdout, res.stderr[-3000:]


def test_flatlandia_config_says_the_files_are_up_to_date(capsys):
    """The check printed nothing on success: a user who just ran it could not tell what it did."""
    from flatlandia import config

    assert cli.main(["config", "--repo", str(REPO)]) == 0
    out = capsys.readouterr().out
    assert "config/config.yaml" in out and "config/README.md" in out
    assert out.rstrip().endswith(f"up to date with {config.SCHEMA_PATH}")


@pytest.mark.slow  # a Snakemake job (the fetch, which fails at once)
def test_a_mistyped_data_folder_says_it_does_not_exist_when_the_fetch_fails(tmp_path):
    """`--config flatlandia_root=/typo`: the fetch's ERROR told to set flatlandia_root, which was set."""
    from snakemake_runner import smk

    cfg = tmp_path / "typo.yaml"
    cfg.write_text(
        f"flatlandia_root: {tmp_path / 'flatlandai'}\n"
        f"fetch: {{url: '{(tmp_path / 'no_archive.zip').as_uri()}', dest: '{tmp_path / 'resources/fetched'}', timeout_s: 5}}\n"
    )
    res = smk(REPO, tmp_path, "--cores", "1", "maps", "--configfile", str(TINY), str(cfg))
    line = _one_error(res)
    assert line.startswith(f"ERROR: the data folder {tmp_path / 'flatlandai'} (flatlandia_root) does not exist, so")
    assert "flatlandia_root=/path/to/data" in line and not (tmp_path / "resources/fetched").exists()


def test_audit_write_never_overwrites_an_artifact_of_the_run(tmp_path, monkeypatch, capsys):
    """`flatlandia audit --write results/.../reference_map.parquet` replaced the map with the manifest."""
    artifact = _one_record(tmp_path)
    monkeypatch.chdir(tmp_path)
    for given in ("results/0/maps/reference_map.parquet", str(artifact)):
        assert cli.main(["audit", "--write", given]) == 1
        assert capsys.readouterr().err.startswith(
            f"ERROR: --write {given}: an artifact of this run (rule reference_map)"
        )
        assert artifact.read_bytes() == b"map"
    assert cli.main(["audit", "--write", "my_manifest.parquet"]) == 0
    assert "wrote my_manifest.parquet: 1 artifacts" in capsys.readouterr().out


def test_localize_out_never_overwrites_its_input_or_an_artifact_of_the_run(tmp_path, monkeypatch, capsys):
    """`--batch results --out results/12/queries/queries.parquet` replaced the run's queries with
    poses; `--query q.json --out q.json` replaced the query with its answer."""
    artifact = _one_record(tmp_path)
    monkeypatch.chdir(tmp_path)
    query = tmp_path / "q.json"
    query.write_text('{"objects": []}')
    assert cli.main(["localize", "--map", "m.parquet", "--query", "q.json", "--out", str(query)]) == 1
    assert (
        capsys.readouterr().err
        == f"ERROR: --out: {query} is an input of this command: write the answer to a new file\n"
    )
    assert query.read_text() == '{"objects": []}'
    given = "results/0/maps/reference_map.parquet"
    assert cli.main(["localize", "--batch", "results", "--out", given]) == 1
    assert capsys.readouterr().err.startswith(f"ERROR: --out: {given} is an artifact of this run (rule reference_map)")
    assert artifact.read_bytes() == b"map"
    (tmp_path / "poses.csv").write_text("mine")  # a file of the user's own is the user's to replace
    assert cli.main(["localize", "--batch", "results", "--out", "poses.csv"]) == 1
    assert "is an artifact" not in capsys.readouterr().err  # it fails on the folder, not on --out


def test_a_command_piped_into_head_ends_without_a_traceback(tmp_path):
    """`flatlandia score ... | head -1` printed Python's BrokenPipeError traceback: the reader had
    left before the command's next line (here the command's write fails as it would then)."""
    import os
    import subprocess
    import sys

    code = (
        "from flatlandia import cli\n"
        "from flatlandia.commands import config_command\n"
        "def gone(args):\n    raise BrokenPipeError(32, 'Broken pipe')\n"
        "config_command.config_files = gone\n"
        "raise SystemExit(cli.main(['config']))\n"
    )
    env = os.environ | {"PYTHONPATH": os.pathsep.join(sys.path)}
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, env=env)
    assert run.returncode == 1 and run.stderr == "", run.stderr


def test_principal_plane_runs_after_ingest_has_checked_the_published_files(tmp_path):
    """A truncated transformations.json was two ERROR lines: ingest's and principal_plane's, run
    side by side; principal_plane now waits for ingest, whose line stops the run."""
    root = tmp_path / "data"
    shutil.copytree(TINY_ROOT, root)
    (root / "maps" / "0" / "class_segmented_point_cloud.ply").write_bytes(b"ply\n")  # only planned, never read
    res = smk_dry_run(
        REPO,
        tmp_path,
        "results/0/objects/principal_plane.json",
        "--configfile",
        str(TINY),
        "--config",
        f"flatlandia_root={root}",
    )
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    block = next(b for b in res.stdout.split("\n\n") if "rule principal_plane:" in b)
    assert "results/0/ingest/ingest.json" in block and "rule ingest:" in res.stdout
