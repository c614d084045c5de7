"""The map: its configuration, periods and layouts, storage, quantisation, codes,
embedding and file."""
