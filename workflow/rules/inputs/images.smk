# Input functions and settings of the rules in rules/images.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


def images_dir(wildcards):
    """The image folder of an images scene (from the sheet's path column)."""
    row = SCENES_SHEET.loc[wildcards.scene]
    if row["source"] != "images":
        raise WorkflowError(f"{config['scenes']}: scene {wildcards.scene} is not an images scene")
    problem = images_folder_problem(wildcards.scene)
    if problem:
        raise WorkflowError(f"{config['scenes']}: images scene {wildcards.scene}: {problem}")
    if row["path"] and config_path(row["path"]).exists():
        return str(config_path(row["path"]))
    return f"resources/images/{wildcards.scene}"  # fetched by rule fetch_images


def fetch_images_note(wildcards):
    """No input: says in one line that the plan downloads an images scene's photos (say_download),
    while its folder is not there."""
    dest = f"resources/images/{wildcards.scene}"
    if not Path(dest).exists():
        row = SCENES_SHEET.loc[wildcards.scene]
        why = "its path is empty"
        if row["path"]:
            where = os.path.abspath(config_path(row["path"]))
            why = f"its path {row['path']!r} does not exist here ({where}): set it to the folder of the photos to skip the download"
        what = f"the photos of images scene {wildcards.scene}"
        say_download(f"images {wildcards.scene}", what, "fetch_images", row["url"], dest, f"{config['scenes']}: {why}")
    return []


def images_fetch_params(wildcards):
    """Where rule fetch_images downloads a scene's images from, and the archive's pinned sha256
    (the sheet's optional sha256 column; empty = not pinned)."""
    row = SCENES_SHEET.loc[wildcards.scene]
    return {"url": row.get("url", ""), "subfolder": row.get("subfolder", ""), "sha256": row.get("sha256", "")}


def images_folder_fingerprint(wildcards):
    """Name, size and modification time of every file of the scene's images folder (metadata.csv
    included), as a param: adding, removing, replacing an image or editing metadata.csv reruns the
    audit and what depends on it (Snakemake reruns a job whose params changed). Empty while a
    folder still has to be fetched."""
    folder = Path(images_dir(wildcards))
    if not folder.is_dir():
        return ""
    entries = sorted(
        f"{p.relative_to(folder)}:{p.stat().st_size}:{p.stat().st_mtime_ns}" for p in folder.rglob("*") if p.is_file()
    )
    return hashlib.sha256("\n".join(entries).encode()).hexdigest()


def sfm_threads():
    """Cores for SfM: 1 when sfm.deterministic (pycolmap then runs single-threaded;
    asking for 2 only kept it waiting for a second free core, to the end of a 2-core run), else 2."""
    return 1 if config["sfm"]["deterministic"] else 2


def segment_gpus():
    """GPUs for segment with config device: cuda (rules/resources.yaml): 1 for the transformers
    backend, none for the offline and precomputed ones (no model)."""
    return 1 if config["segment"]["backend"] == "transformers" else 0


def segment_mem_mb():
    """Memory for segment (MB): 1000 + 80 per megapixel of images.max_megapixels, the largest image
    the audit lets through (measured on the offline backend: docs/measurements.md, "Images branch")."""
    return int(1000 + 80 * config["images"]["max_megapixels"])


def scene_align_keys(*keys):
    """The config keys of images.align as a rule's params (named as config_keys names them: the section
    `images.align` or `images.align.mode`), per scene: the scene's align cell in the scene sheet sets
    its mode (align_mode), so scenes with and without GPS are built in one run."""

    def param_of(key):
        def param(wildcards):
            section = {**config["images"]["align"], "mode": align_mode(wildcards.scene)}
            return section if key == "images.align" else section[key.removeprefix("images.align.")]

        return param

    return {key: param_of(key) for key in keys}
