# Flatlandia: regenerate the object-map 3DoF localization benchmark end to end.
# Run: snakemake --cores 2 all   (see README.md; config/README.md documents every setting)
from snakemake.utils import min_version

min_version("9.0")


configfile: "config/config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/queries.smk"
include: "workflow/rules/tables.smk"


rule all:
    input:
        all_targets(),
    default_target: True
