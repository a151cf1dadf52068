"""The package version (read by the command line and by the build, without importing the
package)."""

__version__ = "0.2.0"
