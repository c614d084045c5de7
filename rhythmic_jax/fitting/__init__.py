"""Descriptors -> templates around the solvers: the fit's plan, closed-form and
learned embeddings, fits larger than memory or one process."""
