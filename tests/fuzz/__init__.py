"""Property-based fuzzing of the CLI and the upload route with damaged real clips (issue 13)."""
