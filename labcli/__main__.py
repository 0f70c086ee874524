from labcli.commands.launch import main

main()
