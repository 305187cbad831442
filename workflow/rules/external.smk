# External methods (config `external`): a method's own poses of the test queries, scored with the
# functions of rule fine_eval (flatlandia.score), so that its runs {name}_{map_type}_{proposal} sit in
# the fine table, the error figures, the query figures and the viewers beside the built-in methods
# (fine_runs() lists them; paths.run_file finds their files). Their tree is their own,
# results/external/{name}_{map_type}_{proposal}/. The poses file is an input: editing it rescores the runs.


include: "inputs/external.smk"


rule external_eval:
    input:
        unpack(external_eval_inputs),
    output:
        errors=paths.external_run(),
        summary=paths.external_run(part="summary.json"),
    log:
        "logs/external_eval/{method}_{map_type}_{proposal}.log",
    wildcard_constraints:
        method=external_method_pattern(),
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("external_eval")
    resources:
        **rule_resources("external_eval"),
    params:
        **config_keys("fine.coarse_strategy", "coarse.solver.fine_strategy", reads=strategy_reads),
    script:
        "../scripts/external_eval.py"
