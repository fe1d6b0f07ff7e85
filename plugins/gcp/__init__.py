"""ODM/OpenSfM GCP lists and GNSS projection centres (stages gcp-list, gnss-centres)."""
