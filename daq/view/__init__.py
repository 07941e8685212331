"""What a person sees: rerun recordings and live view (``recording``, ``lane``, ``build``) — docs/view.md."""
