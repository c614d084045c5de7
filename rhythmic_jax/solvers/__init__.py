"""Solvers of the one objective: Newton-CG (exact, with its preconditioner and the
span of the frames for wide descriptors), optax loops (full-batch L-BFGS,
minibatch Adam), resumable runs over batches streamed from disk, the memory
guard, and sharding over frames and templates."""
