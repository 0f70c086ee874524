"""skrl as a lab framework plugin."""
