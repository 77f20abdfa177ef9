import staging_variants  # noqa: F401  (the variant, in every process: staging_variants.py)
