"""The measurement method on arrays and recordings: estimators, the paper's delays, identification,
force error, operating points and settling; the live chain and the compensator use these."""
