# Flatlandia: regenerate the object-map 3DoF localization benchmark end to end.
# Run: snakemake --cores 2 all   (see README.md; config/README.md documents every setting)
import os

from snakemake.utils import min_version

min_version("9.0")


# The default config sits beside this file; --configfile/--config override it.
configfile: os.path.join(workflow.basedir, "config/config.yaml")


include: "workflow/rules/common.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/queries.smk"
include: "workflow/rules/images.smk"
include: "workflow/rules/objects.smk"
include: "workflow/rules/coarse.smk"
include: "workflow/rules/fine.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/tables.smk"


rule all:
    default_target: True
    input:
        all_targets(),


# The maps of the selected scenes only: `snakemake --cores 2 maps --config select=[Paris]`.
rule maps:
    input:
        map_products(),


# The dataset tables, the trained models and the localization tables (Tables 2-5).
rule benchmark:
    input:
        benchmark_products(),


onsuccess:
    # what was built per scene, what is empty and why: on the terminal and in results/summary.md
    from flatlandia import summary

    print(summary.write_summary("results", selected_scenes()))
