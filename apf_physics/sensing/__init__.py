"""What a robot senses: windows of the potential, its memory of visited cells and the map view
(``observation``), and the range sensor (``lidar``)."""
