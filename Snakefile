# Flatlandia: regenerate the object-map 3DoF localization benchmark end to end.
# The design's layout: `snakemake --cores 2 all` from the repository root finds this file. The
# workflow itself is workflow/Snakefile (the Snakemake workflow catalog's layout, which
# `snakemake -s workflow/Snakefile` and the catalog use); everything is defined there.


include: "workflow/Snakefile"
