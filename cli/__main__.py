"""``python -m warpscatter.cli`` runs the same click application as the ``warpscatter`` script."""

from .main import main

main()
