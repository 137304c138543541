from bodymetry.cli import main

main()
