from clutt3r_core.cli import main

main()
