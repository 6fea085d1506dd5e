"""Vehicle hydrodynamic identification: the model, the logs made ready, the excitation checks,
the three fitting methods and the identification that strings them together."""
