"""Paper 000's Double Round auction (Guerrero & Oliver) as the ``dr`` allocation family: see docs/dr.md."""
