from hybridsplat.cli import main

main()
