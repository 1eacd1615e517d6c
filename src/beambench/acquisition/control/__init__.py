"""The speed-tracking controller and the speed map it steers by."""
