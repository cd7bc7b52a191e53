def main():
    """Stand-in until the CLI lands."""
