"""The whole-part scenario: ``[part]`` read and expanded, its checks and its process report."""
