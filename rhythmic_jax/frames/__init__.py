"""From files to descriptors: the backbone networks and their weights, compiled
runners, the feature pipeline and its cache, and what a command-line source
means (image folders, tiles, descriptor files)."""
