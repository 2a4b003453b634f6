"""Tables and documents: the benchmark report (Markdown and LaTeX), the discovery report, the README's results section."""
