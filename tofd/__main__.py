from tofd.cli import entry

entry()
