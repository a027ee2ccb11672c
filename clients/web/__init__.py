
__all__: list[str] = []  # the package's API is its modules
