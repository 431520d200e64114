"""`formation sweep`: parameter studies over the in-process simulator (study file, parallel
cases, table, plots)."""
