"""Parts: grouping Gaussians into parts (mask voting, automatic grouping) and the ObjectModel (issue 4)."""
