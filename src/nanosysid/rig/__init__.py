"""The benchmark rig's real flights: getting the authors' logs (:mod:`.fetch`, every file checked
against a SHA-256 manifest) and reading them into the product's streams (:mod:`.logs`), from
which the product's own sync, filter and split make the flights."""
