"""The `lab` command line: one module per command, each parsing its options and calling one
library function of `labcli.runs`. Imports here stay light: a command imports torch and the
learning libraries only when it runs."""
