"""Source demos: recorded from a demonstrator or brought in from a file. Imports core,
method, data and run."""
