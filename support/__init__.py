"""What tests, benches, tools and experiments share (scenes for second engines, generated objects, start
states); not part of the installed package."""
