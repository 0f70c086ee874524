from labcli.launch import main

main()
