"""What tests, benches and experiments share (scenes for second engines, generated objects); not part of the installed package."""
