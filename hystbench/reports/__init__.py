"""What people look at: the paper's reproduction, figures, the material report and the demo."""
