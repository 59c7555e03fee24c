from mhrc.cli import main

main()
