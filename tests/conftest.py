"""Shared fixtures: the real published data (../shared/flatlandia), the Lund photos
(../shared/images/lund) and the Berlin photos and masks (../shared/images/berlin), each fetched as
`make all` fetches it on a clone without ../shared (Berlin from the Lund photos' archive), the
tiny committed scene (tests/data/tiny) and the repo root; and the check of the `slow` mark, which
every test that needs the published data or runs Snakemake jobs carries (written on the test; a test
without it is a collection error naming what to add); `make test-fast` runs the others:
`pytest -m "not slow"`.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import inspect
import os
import types
from pathlib import Path

import pytest
from snakemake_runner import smk

REPO = Path(__file__).resolve().parents[1]
TESTS = REPO / "tests"
# tests/bin first on PATH: its scontrol answers at once where no SLURM controller runs (Snakemake's
# SLURM plugin asks it in every Snakemake process: 9 s each on a machine with SLURM's tools and no
# controller; the SLURM test's own controller is asked as before)
if os.environ.get("PATH", "").split(os.pathsep)[0] != str(TESTS / "bin"):
    os.environ["PATH"] = os.pathsep.join([str(TESTS / "bin"), os.environ.get("PATH", "")])
#: the tiny synthetic scene in the published format, made by tests/data/make_tiny_scene.py
TINY_ROOT = REPO / "tests" / "data" / "tiny"
TINY_SCENE = "0"


def data_root() -> Path:
    """The published data: FLATLANDIA_ROOT, else ../shared/flatlandia, else where `make all` fetches
    it (the config's fetch.dest in the repository: resources/flatlandia)."""
    given = os.environ.get("FLATLANDIA_ROOT")
    if given:
        return Path(given).resolve()
    shared = (REPO.parent / "shared" / "flatlandia").resolve()
    return shared if shared.exists() else fetched_root()


def fetch_workdir(dest: Path) -> Path:
    """The working folder of a fetch into ``dest`` as `make all` makes it: the folder whose
    ``resources/`` holds it (the repository for resources/flatlandia and resources/images/lund), where
    the run keeps its record of what it fetched (flatlandia.data.fetch.FETCH_STATE)."""
    dest = Path(dest).absolute()
    return next((p.parent for p in dest.parents if p.name == "resources"), REPO)


def fetched_root() -> Path:
    from flatlandia import config

    return (REPO / config.section_defaults("fetch")["dest"]).resolve()


#: why the published data could not be fetched for this session ('' when it was not needed or worked)
FETCH_PROBLEM: dict[str, str] = {}


def ensure_published_data(dest: Path, url: str | None = None) -> str:
    """Fetch the published data into ``dest`` the way `make all` does (flatlandia.data.fetch with the
    config's fetch settings; ``url`` or the environment variable FLATLANDIA_FETCH_URL instead of
    fetch.url, e.g. a file:// archive); '' on success, else the problem in one line."""
    import pandas as pd

    from flatlandia import config
    from flatlandia.data import fetch

    cfg = config.section_defaults("fetch")
    url = url or os.environ.get("FLATLANDIA_FETCH_URL") or cfg["url"]
    sheet = pd.read_csv(REPO / "config" / "scenes.tsv", sep="\t", dtype=str, keep_default_na=False)
    try:
        fetch.fetch_flatlandia(
            dest,
            sheet[sheet["source"] == "flatlandia"],
            url,
            float(cfg["timeout_s"]),
            sha256=cfg["sha256"] if url == cfg["url"] else "",
            limits=fetch.Limits.from_dict(cfg),
            workdir=fetch_workdir(dest),  # as `make all`: its working folder's resources/ hold the fetch and its record
            data_folder=dest,
        )
    except fetch.FetchError as e:
        return str(e)
    return ""


# ---------------------------------------------------------------- the OpenSfM photos
#: the images scene of the scene sheet (config/scenes.tsv) whose photos the images tests read
LUND_SCENE = "lund"
#: where `make all` fetches them when the sheet's path is missing (rule fetch_images' output)
LUND_FETCHED = REPO / "resources" / "images" / LUND_SCENE
#: the Berlin photos and their masks (images/01-03.jpg, masks/01-03.jpg.png, the naming pycolmap's
#: mask_path expects): not a scene of the sheet (the workflow does not use them, the tests do), so
#: here: their local folder (relative to the repository), the folder of the same OpenSfM archive as
#: the Lund row's (data/berlin) and where the tests fetch them (beside the Lund photos)
BERLIN_PATH = "../shared/images/berlin"
BERLIN_SUBFOLDER = "data/berlin"
BERLIN_FETCHED = REPO / "resources" / "images" / "berlin"


def lund_source() -> dict[str, str]:
    """The Lund row of the scene sheet: its local ``path`` (relative to the repository:
    ../shared/images/lund), the ``url`` of the public archive and its ``subfolder``, and the
    ``sha256`` pinned for it ('' when the sheet pins none), as rule fetch_images reads them."""
    import pandas as pd

    sheet = pd.read_csv(REPO / "config" / "scenes.tsv", sep="\t", dtype=str, keep_default_na=False)
    row = sheet.set_index("scene").loc[LUND_SCENE]
    return {key: row.get(key, "") for key in ("path", "url", "subfolder", "sha256")}


def berlin_source() -> dict[str, str]:
    """Where the Berlin photos and masks are (:data:`BERLIN_PATH`) and come from: the Lund row's
    archive (OpenSfM's, with its ``sha256`` pin), its subfolder :data:`BERLIN_SUBFOLDER`."""
    return {**lund_source(), "path": BERLIN_PATH, "subfolder": BERLIN_SUBFOLDER}


@contextlib.contextmanager
def fetch_lock():
    """One fetch at a time across the test workers of a session (`make test` runs two, pytest-xdist):
    an exclusive lock on resources/.tests-fetch.lock; a caller checks again for the data once it
    holds the lock (another worker may have fetched them meanwhile)."""
    path = REPO / "resources" / ".tests-fetch.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def find_photos(
    what: str,
    shared: Path,
    dest: Path,
    src: dict[str, str],
    env: tuple[str, ...],
    url: str | None = None,
    shared_is: str = "the scene sheet's path",
) -> tuple[Path, str]:
    """The folder of ``what`` (a set of photos of the OpenSfM archive) and '', or where they were
    looked for and why they are not there, in one line: ``shared`` when it exists; else ``dest``
    when a complete fetch of the same source is there (flatlandia.data.fetch.fetched_before: the
    repository's record of its fetches, so a half-fetched or hand-made folder is not trusted); else fetched into
    ``dest`` the way `make all` does (rule fetch_images: ``src``'s url and subfolder, the config's
    fetch settings; ``url``, or the first environment variable of ``env`` that is set, instead of
    ``src``'s url, e.g. a file:// zip); ``shared_is`` says in the problem where ``shared`` comes from."""

    if shared.is_dir():
        return shared, ""
    url = url or next((os.environ[name] for name in env if os.environ.get(name)), "") or src["url"]
    with fetch_lock():
        return _fetch_photos(what, shared, dest, src, env, url, shared_is)


def _fetch_photos(what, shared, dest, src, env, url, shared_is) -> tuple[Path, str]:
    """:func:`find_photos` under :func:`fetch_lock`: an earlier complete fetch, else a fetch now."""
    from flatlandia import config
    from flatlandia.data import fetch
    from flatlandia.plumbing import files

    if fetch.fetched_before(dest, fetch_workdir(dest)):
        marker = files.read_json(dest / fetch.FETCH_MARKER)
        if marker.get("url") == url and marker.get("subfolder", src["subfolder"]) == src["subfolder"]:
            return dest, ""
    cfg = config.section_defaults("fetch")
    print(f"\n{what} are not at {shared}: fetching them as `make all` does ...", flush=True)
    try:
        fetch.fetch_images(
            url,
            src["subfolder"],
            dest,
            float(cfg["timeout_s"]),
            sha256=src["sha256"] if url == src["url"] else "",
            limits=fetch.Limits.from_dict(cfg),
            workdir=fetch_workdir(dest),
        )
    except fetch.FetchError as e:
        why = " ".join(str(e).splitlines())
        return dest, (
            f"{what} are needed: not at {shared} ({shared_is}), not fetched into {dest}: "
            f"fetching {url} ({src['subfolder']}) failed: {why} For the tests, {env[0]} may also "
            "name a copy of the archive (file://...)"
        )
    return dest, ""


def find_lund_images(shared: Path, dest: Path, url: str | None = None) -> tuple[Path, str]:
    """The Lund photos (:func:`find_photos`: the Lund row of the scene sheet; FLATLANDIA_LUND_URL)."""
    return find_photos("the Lund photos", shared, dest, lund_source(), ("FLATLANDIA_LUND_URL",), url)


def find_berlin_images(shared: Path, dest: Path, url: str | None = None) -> tuple[Path, str]:
    """The Berlin photos and masks (:func:`find_photos`: :func:`berlin_source`; FLATLANDIA_BERLIN_URL,
    else FLATLANDIA_LUND_URL: a copy of the whole OpenSfM archive serves both)."""
    env = ("FLATLANDIA_BERLIN_URL", "FLATLANDIA_LUND_URL")
    return find_photos("the Berlin photos and masks", shared, dest, berlin_source(), env, url, "conftest.BERLIN_PATH")


@functools.cache
def _lund_images() -> tuple[Path, str]:
    return find_lund_images((REPO / lund_source()["path"]).resolve(), LUND_FETCHED)


@functools.cache
def _berlin_images() -> tuple[Path, str]:
    return find_berlin_images((REPO / BERLIN_PATH).resolve(), BERLIN_FETCHED)


def lund_images() -> Path:
    """The Lund photos (29 geotagged Mapillary images): ../shared/images/lund, else where `make all`
    fetches them (resources/images/lund), fetched there first when needed, once a session; a test
    that cannot have them fails with one line saying where they were looked for and why."""
    folder, problem = _lund_images()
    if problem:
        pytest.fail(problem, pytrace=False)
    return folder


def berlin_images() -> Path:
    """The Berlin folder (3 Mapillary images of 3264 x 2448 in images/, their masks in masks/):
    ../shared/images/berlin, else resources/images/berlin, fetched there first when needed, once a
    session, from the OpenSfM archive; a test that cannot have them fails with one line."""
    folder, problem = _berlin_images()
    if problem:
        pytest.fail(problem, pytrace=False)
    return folder


def pytest_collection_finish(session):
    """A session with tests of the slow lane on a machine without the published data (no
    FLATLANDIA_ROOT, no ../shared) fetches it first, as `make all` does, into resources/flatlandia."""
    root = data_root()
    if os.environ.get("FLATLANDIA_ROOT") or (root / "local_maps.json").exists():
        return
    if any(item.get_closest_marker("slow") for item in session.items):
        with fetch_lock():  # the other test worker may be fetching it
            if (root / "local_maps.json").exists():
                return
            print(f"\nthe published data is not at {root}: fetching it as `make all` does ...", flush=True)
            FETCH_PROBLEM["problem"] = ensure_published_data(root)


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def flat_root() -> Path:
    root = data_root()
    if not (root / "local_maps.json").exists():
        why = FETCH_PROBLEM.get("problem") or "set FLATLANDIA_ROOT, or let the tests fetch it (network)"
        pytest.fail(f"the published Flatlandia data is needed at {root}: {why}")
    return root


@pytest.fixture(scope="session")
def lund() -> Path:
    """The folder of the Lund photos (:func:`lund_images`)."""
    return lund_images()


@pytest.fixture(scope="session")
def berlin() -> Path:
    """The folder of the Berlin photos and masks (:func:`berlin_images`)."""
    return berlin_images()


@pytest.fixture(scope="session")
def all_local_maps(flat_root):
    from flatlandia.plumbing import files

    return files.read_json(flat_root / "local_maps.json")


def published_scene(flat_root: Path, scene: str):
    """A published scene's reference map and queries, built from the published data as the
    workflow builds them (the package's recipe, flatlandia.data.scene_inputs; the schema's
    settings: split seed 0)."""
    from flatlandia.data import scene_inputs

    s = scene_inputs.published_scene(flat_root, scene)
    return s.ref, s.queries


@pytest.fixture(scope="session")
def scene9(flat_root):
    """Scene 9's reference map and queries (shared by the fine-stage and coarse-solver tests)."""
    return published_scene(flat_root, "9")


@pytest.fixture(scope="session")
def tiny_root() -> Path:
    """The tiny committed scene (30 objects, 12 queries; no published data needed)."""
    return TINY_ROOT


def smk_dry_run(repo: Path, workdir: Path, *args: str, **kw):
    """``snakemake -n``: plans the jobs, runs none (the fast lane may call it; ``smk`` is slow)."""
    return smk(repo, workdir, "-n", *args, **kw)


# ---------------------------------------------------------------- the slow lane
# The slow mark is written on the test: `@pytest.mark.slow` above it, or `pytestmark =
# pytest.mark.slow` for a module whose tests are all slow. Every test that reads the published data
# or the OpenSfM photos, or runs Snakemake jobs, carries it (so does any other slow test); the fast
# lane (`make test-fast`: pytest -m "not slow") runs the others. What follows does not set the
# mark: at collection it refuses a test that touches those without it (pytest_collection_modifyitems,
# one line per test naming what it touched). A test touches them when it uses a fixture of the
# published data or photos (or one built on them: the closure holds them), or when its code, its
# fixtures' code or the test-module helpers they call reach them (conftest.data_root,
# published_scene, lund_images, berlin_images, a module-level Path under the data, ../shared or the
# photos' fetched folders, such as ROOT = data_root()) or the Snakemake runner (snakemake_runner.smk).
DATA_FIXTURES = {"flat_root", "all_local_maps", "scene9", "lund", "berlin"}


@functools.cache
def _shared_roots() -> tuple[Path, ...]:
    return (data_root(), (REPO.parent / "shared").resolve(), LUND_FETCHED.resolve(), BERLIN_FETCHED.resolve())


def _code_names(code: types.CodeType) -> set[str]:
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):  # nested functions, lambdas, comprehensions
            names |= _code_names(const)
    return names


def _under_shared(value) -> bool:
    if not isinstance(value, Path):
        return False
    path = value.resolve()
    return any(path == root or path.is_relative_to(root) for root in _shared_roots())


def _value_reason(value) -> str | None:
    if value is smk:
        return "runs Snakemake jobs"
    if any(value is f for f in (data_root, published_scene, lund_images, berlin_images)) or _under_shared(value):
        return "reads the published data"
    return None


def _test_helper(func) -> bool:
    """A function of a test module (not conftest's: smk_dry_run runs no job)."""
    path = Path(func.__code__.co_filename).resolve()
    return path.parent == TESTS and path.name != "conftest.py"


def _slow_reason(func, seen: set) -> str | None:
    """Why a function (and the helpers of the test modules it calls, transitively) is slow, or None."""
    func = inspect.unwrap(func)
    code = getattr(func, "__code__", None)
    if code is None or func in seen:
        return None
    seen.add(func)
    module_globals = func.__globals__
    for name in _code_names(code):
        if name not in module_globals:
            continue
        value = module_globals[name]
        reason = _value_reason(value)
        if reason:
            return reason
        if isinstance(value, types.FunctionType) and _test_helper(value):
            reason = _slow_reason(value, seen)
            if reason:
                return f"{reason} via {name}()"
    return None


def item_slow_reason(item) -> str | None:
    """What a collected test touches that makes it slow (the published data, the photos, Snakemake
    jobs), or None; its marks are not looked at."""
    used = DATA_FIXTURES & set(getattr(item, "fixturenames", ()))
    if used:
        return f"uses the published data (fixture {sorted(used)[0]})"
    seen: set = set()
    if isinstance(item, pytest.Function):
        reason = _slow_reason(item.function, seen)
        if reason:
            return reason
        for value in getattr(getattr(item, "callspec", None), "params", {}).values():
            if _under_shared(value):
                return f"reads the published data (parameter {value})"
    info = getattr(item, "_fixtureinfo", None)
    for name in getattr(item, "fixturenames", ()):
        for fixturedef in info.name2fixturedefs.get(name, ()) if info else ():
            reason = _slow_reason(fixturedef.func, seen)
            if reason:
                return f"{reason} (fixture {name})"
    return None


def unmarked_slow_message(unmarked: list[tuple[str, str]]) -> str:
    """The collection error for tests that touch the slow lane's data or jobs without the mark."""
    lines = "\n".join(f"  {nodeid}: {reason}" for nodeid, reason in unmarked)
    return (
        f"{len(unmarked)} test(s) read the published data or the photos, or run Snakemake jobs, without "
        f'the slow mark (the fast lane, pytest -m "not slow", would run them):\n{lines}\n'
        "Add the line `@pytest.mark.slow` directly above each `def test_...` (the module needs "
        "`import pytest`), or, when every test of a module is slow, `pytestmark = pytest.mark.slow` "
        "after its imports."
    )


SLOW_COUNTS = pytest.StashKey[dict]()


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects by marker: an unmarked test is refused in every lane
def pytest_collection_modifyitems(config, items):
    counts = {"published data": 0, "Snakemake jobs": 0, "other": 0, "of": len(items)}
    unmarked = []
    for item in items:
        reason = item_slow_reason(item)
        if item.get_closest_marker("slow") is None:
            if reason:
                unmarked.append((item.nodeid, reason))
            continue
        counts["Snakemake jobs" if reason and "Snakemake" in reason else "published data" if reason else "other"] += 1
    if unmarked:
        raise pytest.UsageError(unmarked_slow_message(unmarked))
    config.stash[SLOW_COUNTS] = counts


def pytest_report_collectionfinish(config, start_path, items):
    c = config.stash.get(SLOW_COUNTS, None)
    if c:
        slow = c["published data"] + c["Snakemake jobs"] + c["other"]
        return (
            f"slow lane (@pytest.mark.slow): {slow} of {c['of']} tests (published data or photos "
            f"{c['published data']}, Snakemake jobs {c['Snakemake jobs']}, other {c['other']}); fast lane: -m 'not slow'"
        )
