"""One router per resource: tables, fits, models; plus health and the API docs."""
