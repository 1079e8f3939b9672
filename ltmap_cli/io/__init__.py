"""Log readers, typed frames and map file readers/writers. Never imports ltmap_cli.core."""
