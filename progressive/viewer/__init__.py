"""`progressive view`: a glfw window over the same Session the CLI renders with."""
