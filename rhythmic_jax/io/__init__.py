"""Files in and out: image-folder traversals, aerial tiles, descriptor files,
what a command-line source means, checkpoints of maps and runs, and the one
atomic writer everything on disk goes through."""
