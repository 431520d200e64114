"""Build-time tools of the compiled firmware core (mypyc): never imported at run time."""
