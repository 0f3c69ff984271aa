"""Studies that compare the corridor with other approaches. The services never import them."""
