"""Control: embedded model, EMC, PI baseline, excitation signals, schema and design."""
