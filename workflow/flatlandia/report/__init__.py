"""How results are written and drawn, for every stage alike: ``tables`` (each result table's schema,
checked when written as Parquet, Markdown and LaTeX) and ``figures`` (one style per method, map type
and proposal; the report's figures). The stages' own tables build their rows on these:
``flatlandia.fine.fine_table``, ``flatlandia.city.city_table``, ``flatlandia.sequences.sequence_table``.
"""
