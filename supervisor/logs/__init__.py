"""Flight logs (writer and reader), reports from them, and the logging set-up."""
