"""Solvers of the one objective, all answering ``run(init_params, *args)``
(:mod:`~rhythmic_jax.solvers.protocol`): Newton-CG as optax transformations
(:mod:`~rhythmic_jax.solvers.newton_cg`; driven with its preconditioner and the
span of the frames for wide descriptors by :mod:`~rhythmic_jax.solvers.newton`),
optax loops (full-batch L-BFGS, minibatch Adam; the optimiser travels in the
training state), Newton-CG over frames streamed from disk in blocks
(:mod:`~rhythmic_jax.solvers.streamed`, the same transformation), resumable runs
over batches streamed from disk, the memory guard, and one fit with its frames
sharded over processes (:mod:`~rhythmic_jax.solvers.distributed`)."""
