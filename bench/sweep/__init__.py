"""Many runs: a sweep's plan, studies (``conf/study/NAME.yaml``) and the summary a sweep prints."""
