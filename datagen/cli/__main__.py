"""``python -m datagen.cli`` runs the ``datagen`` command."""
from .main import main

main()
