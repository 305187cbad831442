"""The work of each ``flatlandia`` command, one module per command, OpenSfM's way (its parser and
dispatch stay in one place, :mod:`flatlandia.cli`): ``audit_command``, ``config_command``,
``debug_command``, ``localize_command`` (``--batch`` too) and ``score_command``; what they share,
``messages`` (the ``ERROR:`` and ``WARNING:`` lines) and ``out_option`` (a command's ``--out``,
refused before any work where it would replace what the run holds, and written whole)."""
