"""File formats: image-folder traversals, aerial tiles, descriptor and frame
files, checkpoints of maps and runs, and the one atomic writer everything on
disk goes through."""
