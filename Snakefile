# Flatlandia: regenerate the object-map 3DoF localization benchmark end to end.
# The design's layout: `snakemake --cores 2` (or `snakemake -n`, `snakemake --report ...`) from the
# repository root finds this file. The workflow itself is workflow/Snakefile (the Snakemake workflow
# catalog's layout, which `snakemake -s workflow/Snakefile`, modules and the catalog use); everything
# is defined there.


include: "workflow/Snakefile"


# `include` keeps the including file's default target (Snakemake issues #2056, #2773), so `rule all`'s
# `default_target: True` is restored here: `snakemake` without a target builds `all`.
workflow.default_target = "all"
