"""The application: the command line, its jobs and the demo."""
