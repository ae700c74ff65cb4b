"""What people read: figures (each takes an Axes), the HTML reports of fit, posterior and diagnosis
runs, the fleet page, and a finished run re-opened for them."""
