"""``flatlandia debug RULE key=value ...``: one job of the workflow built with Snakemake's own API and
its rule's script run in this process, where breakpoints and print work (flatlandia.plumbing.debug)."""

from __future__ import annotations

from flatlandia.commands.messages import error
from flatlandia.plumbing import escape


def debug_rule(args) -> int:
    """Build one job of the workflow and run its script here (``--show``: only print the job)."""
    from snakemake.cli import parse_config

    from flatlandia.plumbing import debug

    wildcards = {}
    for item in args.wildcards:
        key, sep, value = item.partition("=")
        if not sep or not key:
            error(f"wildcard {item!r}: expected key=value, e.g. scene=12")
            return 2
        wildcards[key] = value
    try:
        smk = debug.mock_snakemake(
            args.rule,
            workdir=args.directory,
            configfiles=args.configfile,
            config=parse_config(args.config),
            snakefile=args.snakefile,
            cores=args.cores,
            **wildcards,
        )
    except debug.DebugError as e:
        error(str(e))
        return 2
    if args.log_to_terminal:
        smk.log = type(smk.log)()  # no log file: the script's logger writes to stderr
    print("\n".join(map(escape.terminal, debug.describe(smk).split("\n"))), flush=True)  # config values
    if args.show:
        return 0
    print(f"running {smk.script.name} in this process ...", flush=True)
    try:
        debug.run_script(smk)
    except debug.DebugError as e:
        error(str(e))
        return 2
    except SystemExit as e:  # rule_log.run ends a script with bad input with exit status 1
        return int(e.code or 0) if not isinstance(e.code, str) else 1
    except Exception:
        if not args.pdb:
            raise
        import pdb
        import traceback

        traceback.print_exc()
        pdb.post_mortem()
        return 1
    print("done; outputs:")
    for p in smk.output:
        print(f"  {escape.terminal(p)}{'' if (smk.workdir / p).exists() else ' (not written)'}")
    if smk.log:
        print(f"log: {escape.terminal(smk.log[0])}")
    return 0
