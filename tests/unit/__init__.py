"""In-process tests of one unit or a few: no sockets, no child processes (a file whose tests are mostly
such may keep a run or two of its topic, marked slow)."""
