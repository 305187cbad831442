# Ablations (target `ablations`, not in `all`): what a result owes to one part, as rows beside the
# benchmark's own: the solver without the training split's camera prior on the whole map, and the
# sequence and fix protocol's scene rows without it. results/tables/ablations.{md,parquet} (the
# fine rows) and ablations_one_frame.parquet (the protocol's rows), in the fine and beyond schemas.


include: "inputs/ablations.smk"


rule ablations_table:
    input:
        unpack(ablations_table_inputs),
    output:
        fine=paths.table("ablations"),
        beyond=paths.table("ablations_one_frame"),
        markdown=paths.table("ablations", "md"),
    log:
        "logs/ablations_table/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("ablations_table")
    resources:
        **rule_resources("ablations_table"),
    params:
        **config_keys("beyond.split", "beyond", exclude=BEYOND_CITIES),
    script:
        "../scripts/ablations_table.py"
