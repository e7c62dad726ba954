"""Tables, figures, HTML reports and the `dynid` command line."""
