"""The ``warpscatter`` command-line application (click), installed as ``warpscatter.cli``.

It is a thin layer over the library: ``render`` runs :func:`warpscatter.pipeline.render` on a
validated config, ``validate`` checks a config, ``bench`` runs :func:`warpscatter.bench.run`.
The entry point is :func:`warpscatter.cli.main.main`.
"""
