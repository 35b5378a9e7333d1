"""Expected status counts of a run in which every sample converged."""

STATUS_NAMES = ("converged", "max_iterations", "invalid_input", "ambiguous", "out_of_volume",
                "not_converged")


def converged_only(n: int) -> dict[str, int]:
    """``status_counts`` (every status named, zeros included) when all ``n`` samples converged."""
    return {name: (n if name == "converged" else 0) for name in STATUS_NAMES}
