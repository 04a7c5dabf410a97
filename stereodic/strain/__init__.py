"""Strain from displacement fields: the virtual strain gauge (`fit`: a local polynomial fit of the
displacements), the strain measures (`measures`) and strain of saved DIC results (`results`)."""
